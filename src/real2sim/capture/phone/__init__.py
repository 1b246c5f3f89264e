"""Phone photos and video: structure from motion, the printed board, frames from a video, and the move of
an SfM model into metres, the table plane and the robot frame (normalisation).
"""
