"""mocap_rt.fusion"""
