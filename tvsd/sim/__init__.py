"""tvsd.sim"""
