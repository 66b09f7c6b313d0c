"""Drawing (OpenCV, arrays only) and command-line pictures; never steps physics.

``truckrl.viz.draw`` renders scenes, trucks, goals and LiDAR into RGB arrays for the interactive
viewer, training videos and ``truckrl tools scenes``.
"""

from truckrl.viz.draw import COLORS, View, draw_scene, make_view, world_to_pixel

__all__ = ["COLORS", "View", "draw_scene", "make_view", "world_to_pixel"]
