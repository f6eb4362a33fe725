"""Settings declared once: a config dataclass's fields carry their help, and command-line options are
generated from them.

`setting(default, help)` declares a field. `add_settings_arguments` turns each field into `--field-name`
(or the field's `flag`), typed by its annotation: int, float, str, a `Literal` of choices, a list or
tuple of ints (written "64,64"), each optionally `| None`; a bool that defaults to False becomes a switch
`--field-name`, one that defaults to True a switch `--no-field-name`. Options default to None ("keep the
config's default"), so `settings_from_args` returns only what the user set and the config's own defaults
and validation apply to the rest.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from collections.abc import Callable
from typing import Any, Literal

_SCALARS = (int, float, str)


def setting(
    default: Any = dataclasses.MISSING,
    help: str = "",
    *,
    flag: str | None = None,
    metavar: str | None = None,
    factory: Callable[[], Any] | None = None,
    parse: Callable[[str], Any] | None = None,
) -> Any:
    """A config field with the one-line help the CLI shows; `flag` names its option where the field's name
    would not, `factory` builds a mutable default, `parse` reads the option's text where the type does not
    say how (e.g. `index_list`)."""
    metadata = {"help": help, "flag": flag, "metavar": metavar, "parse": parse}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def int_list(text: str) -> list[int]:
    """ "64,64" -> [64, 64]: comma-separated whole numbers (no ranges: a layer list is not an index set)."""
    try:
        values = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, e.g. 64,64; got {text!r}") from None
    return values


def index_list(text: str) -> tuple[int, ...]:
    """ "0-24" or "0,3,5-9" -> the listed indices, in order; ranges are inclusive."""
    out: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        low, dash, high = part.partition("-")
        try:
            first, last = int(low), int(high) if dash else int(low)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected indices and ranges, e.g. 0-24 or 0,3,5-9") from None
        if last < first:
            raise argparse.ArgumentTypeError(f"{text!r}: range {part!r} runs backwards")
        out += range(first, last + 1)
    if not out:
        raise argparse.ArgumentTypeError(f"{text!r}: expected at least one index")
    return tuple(out)


def _option(annotation: Any) -> tuple[Callable[[str], Any], tuple[Any, ...] | None]:
    """(argparse type, choices) of a field annotation; None-able unions read as their other member."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        (annotation,) = [a for a in typing.get_args(annotation) if a is not type(None)]
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Literal:
        return type(args[0]), args
    if origin in (list, tuple) and args and args[0] is int:
        return int_list, None
    if annotation in _SCALARS:
        return annotation, None
    raise TypeError(f"no command-line option for a field of type {annotation!r}")


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else None


def add_settings_arguments(parser: argparse.ArgumentParser, config_cls: type, exclude: tuple[str, ...] = ()) -> None:
    """One option per field of `config_cls` (a dataclass) not in `exclude`."""
    hints = typing.get_type_hints(config_cls)
    for f in dataclasses.fields(config_cls):
        if f.name in exclude:
            continue
        default, help_text, flag = _default(f), f.metadata.get("help", ""), f.metadata.get("flag")
        if hints[f.name] is bool:
            switch = flag or ("--no-" if default else "--") + f.name.replace("_", "-")
            parser.add_argument(
                switch, dest=f.name, action="store_const", const=not default, default=None, help=help_text
            )
            continue
        kind, choices = _option(hints[f.name])
        kind = f.metadata.get("parse") or kind
        if default is not None:
            shown = ",".join(map(str, default)) if isinstance(default, (list, tuple)) else default
            help_text += f" (default: {shown})"
        parser.add_argument(
            flag or "--" + f.name.replace("_", "-"),
            dest=f.name,
            type=kind,
            choices=choices,
            default=None,
            metavar=f.metadata.get("metavar"),
            help=help_text,
        )


def settings_from_args(args: argparse.Namespace, config_cls: type, exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of `config_cls` the user set on the command line (options left out stay unset)."""
    names = [f.name for f in dataclasses.fields(config_cls) if f.name not in exclude]
    return {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}
