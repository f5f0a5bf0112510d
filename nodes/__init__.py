"""Processes of the capture service: sync, camera workers, fusion, recorder, viewer, launcher."""
