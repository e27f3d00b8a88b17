"""tvsd.cli"""
