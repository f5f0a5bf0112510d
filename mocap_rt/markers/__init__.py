"""mocap_rt.markers"""
