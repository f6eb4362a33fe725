"""The annotated-episode dataset: HDF5 layout, reading/writing, features for multi-task models, labelling."""
from annotations.dataset import Demo, DemoFile, DemoWriter, read_attrs
from annotations.features import TaskFeatureEncoder
from annotations.format import ANNOTATION_SCHEMA_VERSION, CRITERIA, FORMAT_VERSION, SEGMENT_LENGTH, task_key

__all__ = [
    "ANNOTATION_SCHEMA_VERSION", "CRITERIA", "Demo", "DemoFile", "DemoWriter", "FORMAT_VERSION", "SEGMENT_LENGTH",
    "TaskFeatureEncoder", "read_attrs", "task_key",
]
