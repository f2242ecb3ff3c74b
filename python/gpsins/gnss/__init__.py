"""GNSS measurements on their own: single-point positioning over a data set (``spp``) and the
ionosphere from a second frequency (``ionosphere``).
"""
