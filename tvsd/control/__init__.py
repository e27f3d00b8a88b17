"""tvsd.control"""
