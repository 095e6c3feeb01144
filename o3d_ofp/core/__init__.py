"""Core: the numerical routines over plain arrays (never Open3D).

Laplacian, eigenbasis, eigenproducts, orthogonalization, the OFP basis, descriptors,
functional maps, point-to-point maps, transfer, filtering and the paper's baselines.
"""
