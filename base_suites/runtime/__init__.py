"""Project-wide runtime utilities, light to import (no simulator, no torch): one-line user errors
(`errors`), atomic file output and run-config checks (`io`), process pools and Ray actors for episodes
(`jobs`, `ray_jobs`), seed derivation (`seeds`) and lazy package exports (`lazy`)."""

from base_suites.runtime.errors import UserInputError, unknown_choice
from base_suites.runtime.io import atomic_write, atomic_write_json, changed_fields, read_json_file
from base_suites.runtime.jobs import Workers, available_cores, check_workers, run_jobs
from base_suites.runtime.lazy import lazy_getattr
from base_suites.runtime.seeds import derive_seed

__all__ = [
    "UserInputError",
    "Workers",
    "atomic_write",
    "atomic_write_json",
    "available_cores",
    "changed_fields",
    "check_workers",
    "derive_seed",
    "lazy_getattr",
    "read_json_file",
    "run_jobs",
    "unknown_choice",
]
