"""Photo carving: voxels that the views' colours disagree on are removed, with the views' exposure
evened out and the masks rechecked against the field.
"""
