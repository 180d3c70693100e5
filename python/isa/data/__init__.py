"""Data in: meshes, ModelNet10, procedural instances, SUN RGB-D frames, other sensors' depth
formats (TUM, NYU) and the BOP format."""

from isa._reexport import lazy_reexport

# The subpackage's public names by module (a table, shaped like every subpackage's; `duplicates`
# pairs it with evaluation's).
__getattr__, __dir__, __all__ = lazy_reexport(__name__, {
    "meshes": [
        "MESH_EXTENSIONS", "load_mesh", "object_origin", "real_size_scale", "rescale_to_real_size",
        "to_object_frame", "prepare_mesh",
    ],
    "modelnet": [
        "SPLITS", "Instance", "find_root", "list_instances", "paper_instances", "VALIDATION_INSTANCES",
        "validation_instances",
    ],
    "procedural": [
        "SKELETON_TEMPLATES", "template", "ProceduralObject", "generate", "skeleton_segments", "generate_many",
    ],
    "sunrgbd": [
        "SceneFrame", "UPRIGHT_FROM_CAMERA_AXES", "read_native", "read_processed", "list_native",
        "list_processed", "iter_processed", "decode_sun_depth", "NON_OBJECT_CLASSES",
    ],
    "sensors": [
        "TUM_UNITS_PER_METRE", "NYU_DISPARITY", "NYU_NO_READING", "NYU_MAX_DEPTH_M", "read_tum_depth",
        "read_nyu_pgm", "read_nyu_annotated", "read_depth",
    ],
    "bop": [
        "MAX_DEPTH_UNITS", "write_json", "read_json", "depth_to_png", "png_to_depth", "model_info",
        "model_path", "write_model", "read_model", "BopFrame", "scene_dir", "SceneWriter", "list_scenes",
        "list_frames", "read_frame", "read_scene", "FrameSequence", "MappedFrames", "frame_obj_ids",
        "write_models_info", "read_models_info",
    ],
})
