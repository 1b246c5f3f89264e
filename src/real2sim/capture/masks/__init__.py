"""Object masks, every method: provided, Mask R-CNN with local weights, background difference, and the
parallax masks from the images and poses alone; the mask stage that applies one to a dataset copy.
"""
