"""The command line of the benchmarks built on the chain (`elegant.pipeline.run_chain`): a recipe file
and, generated from `ChainConfig`, one option per setting that overrides it."""

from __future__ import annotations

import argparse

from base_suites.runtime.jobs import add_workers_argument
from base_suites.runtime.settings import add_settings_arguments, settings_from_args, with_overrides
from elegant.chain_config import ChainConfig, load_recipe


def add_chain_arguments(parser: argparse.ArgumentParser, recipe: str) -> None:
    """--out, --recipe (default `recipe`, a name under configs/ or a YAML file), every chain setting, --workers."""
    parser.add_argument("--out", required=True, help="chain directory (resumable)")
    parser.add_argument("--recipe", default=recipe, help=f"a recipe under configs/ or a YAML file (default: {recipe})")
    add_settings_arguments(parser, ChainConfig, show_defaults=False)
    add_workers_argument(parser)


def chain_config(args: argparse.Namespace) -> ChainConfig:
    """The recipe with the settings given on the command line."""
    return with_overrides(load_recipe(args.recipe), settings_from_args(args, ChainConfig), "command line")
