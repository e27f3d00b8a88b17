"""tvsd.daemon"""
