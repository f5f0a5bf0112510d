"""mocap_rt.studio"""
