"""Writers of the asset's model files: URDF for Drake, portable URDF, point-contact URDF, SDFormat, MJCF
(MuJoCo) and USD (Isaac), and the round pieces they share.
"""
