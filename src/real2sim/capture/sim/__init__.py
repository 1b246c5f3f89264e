"""Simulated capture in Drake: a wrist camera on a robot arm, hard rigs (turntable rings, long lenses, cut-off
views, exposure, JPEG), handheld phone captures with the printed board, and the dataset they write.
"""
