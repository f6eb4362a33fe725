"""Command-line options generated from a frozen config dataclass, so a setting is declared once.

Each field becomes `--field-name` (or its metadata's `flag`), typed by its annotation (int, float, str,
a `Literal` of choices, optionally `| None`), with the field's metadata `help`. Options default to None
("keep the config's default"), so `settings_from_args` returns only what the user set, and the config's
own defaults and validation apply to the rest.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from typing import Any, Literal

_SCALARS = (int, float, str)


def _option_type(annotation: Any) -> tuple[Any, tuple[Any, ...] | None]:
    """(argparse type, choices) of a field annotation; None-able unions read as their other member."""
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        (annotation,) = [a for a in args if a is not type(None)]
        args = typing.get_args(annotation)
    if typing.get_origin(annotation) is Literal:
        return type(args[0]), args
    if annotation in _SCALARS:
        return annotation, None
    raise TypeError(f"no command-line option for a field of type {annotation!r}")


def add_settings_arguments(parser: argparse.ArgumentParser, config_cls: type, exclude: tuple[str, ...] = ()) -> None:
    """One option per field of `config_cls` (a dataclass) not in `exclude`."""
    hints = typing.get_type_hints(config_cls)
    for f in dataclasses.fields(config_cls):
        if f.name in exclude:
            continue
        kind, choices = _option_type(hints[f.name])
        flag = f.metadata.get("flag") or "--" + f.name.replace("_", "-")
        default = f.default if f.default is not dataclasses.MISSING else None
        help_text = f.metadata.get("help", "")
        if default is not None:
            help_text += f" (default: {default})"
        parser.add_argument(flag, dest=f.name, type=kind, choices=choices, default=None, help=help_text)


def settings_from_args(args: argparse.Namespace, config_cls: type, exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of `config_cls` the user set on the command line (options left out stay unset)."""
    names = [f.name for f in dataclasses.fields(config_cls) if f.name not in exclude]
    return {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
