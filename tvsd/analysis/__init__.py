"""tvsd.analysis"""
