"""tvsd.model"""
