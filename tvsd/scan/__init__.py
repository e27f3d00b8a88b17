"""tvsd.scan"""
