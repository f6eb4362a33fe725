"""LIBERO and LIBERO-PRO tasks as gymnasium environments, perturbations, and a read-only simulator view."""

from base_suites.env import SETTLE_ACTION, LiberoEnv, make_env
from base_suites.perturbations import PERTURBATIONS, Perturbation, make_perturbation, parse_perturbations
from base_suites.runtime.errors import UserInputError
from base_suites.sim_view import Contact, Region, SimView
from base_suites.stack import SIMULATOR_FIELDS, TRAINING_FIELDS, check_same_stack, stack_mismatch, stack_record
from base_suites.suites import MAX_STEPS, TaskSpec, get_task, list_suites, list_tasks, task_order, task_specs

__all__ = [
    "Contact",
    "LiberoEnv",
    "MAX_STEPS",
    "PERTURBATIONS",
    "SETTLE_ACTION",
    "SIMULATOR_FIELDS",
    "Perturbation",
    "Region",
    "SimView",
    "TRAINING_FIELDS",
    "TaskSpec",
    "UserInputError",
    "check_same_stack",
    "get_task",
    "list_suites",
    "list_tasks",
    "make_env",
    "make_perturbation",
    "parse_perturbations",
    "stack_mismatch",
    "stack_record",
    "task_order",
    "task_specs",
]
