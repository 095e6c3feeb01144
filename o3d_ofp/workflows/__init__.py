"""Workflows over arrays: whole match, transfer, detail and filtering runs, and the basis cache.

The rules that tie core steps together (how many eigenfunctions a map estimation needs, which
map feeds which transfer) live here, once.
"""
