"""mocap_rt.io"""
