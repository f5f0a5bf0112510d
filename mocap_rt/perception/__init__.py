"""mocap_rt.perception"""
