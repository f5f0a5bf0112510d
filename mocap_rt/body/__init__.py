"""mocap_rt.body"""
