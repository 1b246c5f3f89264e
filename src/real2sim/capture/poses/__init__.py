"""Pose refinement of given (robot) poses with COLMAP, re-aligned to the robot frame, and its quality gate.
"""
