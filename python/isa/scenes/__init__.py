"""Scenes: cluttered rooms and real-scan views with exact 6D ground truth, in the BOP format.

``cameras`` (hand-held / mounted Kinect poses), ``rooms`` (floor, walls, instances, clutter),
``sources`` (where instance meshes come from), ``writer`` (the BOP dataset on disk), ``scan2cad``
(the real ScanNet scan as a scene), ``io`` (reading a scene dataset back for scoring).
"""

from isa.scenes.io import GroundTruth, SceneFrame, read_scene_dataset
from isa.scenes.scan2cad import make_scan2cad_scenes
from isa.scenes.sources import MeshSource, modelnet_protocol, modelnet_test, modelnet_validation, procedural
from isa.scenes.writer import make_scenes

__all__ = ["GroundTruth", "MeshSource", "SceneFrame", "make_scan2cad_scenes", "make_scenes", "modelnet_protocol", "modelnet_test",
           "modelnet_validation", "procedural", "read_scene_dataset"]

# Scoring and the benchmark (the scoring helper's part).
from isa.scenes.scoring import Detection, Scores, evaluate

__all__ += ["Detection", "Scores", "evaluate"]
