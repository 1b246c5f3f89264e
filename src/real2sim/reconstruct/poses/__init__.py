"""Camera poses recovered from silhouettes (the hull's leave-one-out surfaces) and placement by the
object's size.
"""
