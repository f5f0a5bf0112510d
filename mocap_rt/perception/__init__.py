"""Per-camera 2D perception (seed digest A.1, A.2, A.4, B.8): image -> ``CameraCues``.

``pipeline.CameraPerceiver`` is the entry point; ``background`` (silhouette),
``colour_model`` (parametric skin/shoe colour), ``blobs``/``blob_kernels``/``region_kernels``
(deformable-ellipse blob tracking, region snap and re-acquisition), ``torso`` (torso point). See ``docs/perception.md``.
"""
