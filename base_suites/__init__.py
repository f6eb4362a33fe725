"""LIBERO and LIBERO-PRO tasks as gymnasium environments, perturbations, and a read-only simulator view."""

from base_suites.env import LiberoEnv, make_env
from base_suites.perturbations import PERTURBATIONS, Perturbation, make_perturbation, parse_perturbations
from base_suites.runtime.errors import UserInputError
from base_suites.sim_view import Contact, Region, SimView
from base_suites.suites import MAX_STEPS, TaskSpec, get_task, list_suites, list_tasks, task_order, task_specs

__all__ = [
    "Contact",
    "LiberoEnv",
    "MAX_STEPS",
    "PERTURBATIONS",
    "Perturbation",
    "Region",
    "SimView",
    "TaskSpec",
    "UserInputError",
    "get_task",
    "list_suites",
    "list_tasks",
    "make_env",
    "make_perturbation",
    "parse_perturbations",
    "task_order",
    "task_specs",
]
