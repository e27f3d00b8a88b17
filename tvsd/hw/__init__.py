"""tvsd.hw"""
