"""The annotated-episode dataset: HDF5 layout, reading/writing, features for multi-task models, labelling."""

from annotations.dataset import Demo, DemoFile, DemoWriter, read_attrs
from annotations.features import (
    ENCODINGS,
    Encoding,
    FeatureEncoder,
    TaskFeatureEncoder,
    encoder_from_dict,
    make_encoder,
)
from annotations.format import ANNOTATION_SCHEMA_VERSION, CRITERIA, FORMAT_VERSION, SEGMENT_LENGTH, task_key
from annotations.goal_features import GoalContext, GoalFeatureEncoder
from annotations.human_labels import HumanLabel, apply_human_labels, export_segment_labels, read_human_labels
from annotations.labelling import annotate_file, discounted_return_to_go, replay_verdict

__all__ = [
    "ANNOTATION_SCHEMA_VERSION",
    "CRITERIA",
    "Demo",
    "ENCODINGS",
    "Encoding",
    "FeatureEncoder",
    "GoalContext",
    "GoalFeatureEncoder",
    "DemoFile",
    "DemoWriter",
    "FORMAT_VERSION",
    "HumanLabel",
    "SEGMENT_LENGTH",
    "TaskFeatureEncoder",
    "annotate_file",
    "apply_human_labels",
    "discounted_return_to_go",
    "encoder_from_dict",
    "export_segment_labels",
    "make_encoder",
    "read_attrs",
    "read_human_labels",
    "replay_verdict",
    "task_key",
]
