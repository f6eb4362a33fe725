"""Settings declared once: a config dataclass's fields carry their help; command-line options, recipe files
and overrides are all read through them (docs/design.md, configuration).

`setting(default, help)` declares a field. A field whose type is itself a config dataclass nests that
config (the chain composes its stages' configs): `nested(factory, prefix, derived)` declares it, with the
prefix its options take and the fields its owner sets itself (left out of the options and refused in a
recipe). `add_settings_arguments` turns each field into `--prefix-field-name` (or the field's `flag`),
typed by its annotation: int, float, str, a `Literal` of choices, a list or tuple of ints ("64,64") or of
strings ("a,b"), each optionally `| None`; a bool that defaults to False becomes a switch
`--field-name`, one that defaults to True a switch `--no-field-name`. Options default to None ("keep the
config's value"), so `settings_from_args` returns only what the user set, nested like the config.
`load_config` reads a recipe (YAML) into a config, `with_overrides` applies nested settings to one.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any, Literal

from base_suites.runtime.errors import UserInputError, unknown_choice

_SCALARS = (int, float, str)


def setting(
    default: Any = dataclasses.MISSING,
    help: str = "",
    *,
    flag: str | None = None,
    metavar: str | None = None,
    factory: Callable[[], Any] | None = None,
    parse: Callable[[str], Any] | None = None,
    choices: Callable[[], tuple[str, ...]] | None = None,
    label: str | None = None,
) -> Any:
    """A config field with the one-line help the CLI shows; `flag` names its option where the field's name
    would not, `factory` builds a mutable default, `parse` reads the option's text where the type does not
    say how (e.g. `index_list`), `choices` returns a `str` field's values where a registry, not a `Literal`,
    holds them (asked each time, so a value registered later counts), `label` names the field in a refusal
    (`check_choices`) where its name would not."""
    metadata = {"help": help, "flag": flag, "metavar": metavar, "parse": parse, "choices": choices, "label": label}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def nested(factory: Callable[[], Any], prefix: str, derived: tuple[str, ...] = ()) -> Any:
    """A field holding another config: its options are `--{prefix}{field}`; `derived` names the fields
    the owning config sets itself (they get no option and a recipe may not set them)."""
    return dataclasses.field(default_factory=factory, metadata={"prefix": prefix, "derived": derived})


def int_list(text: str) -> list[int]:
    """ "64,64" -> [64, 64]: comma-separated whole numbers (no ranges: a layer list is not an index set)."""
    try:
        values = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, e.g. 64,64; got {text!r}") from None
    return values


def str_list(text: str) -> tuple[str, ...]:
    """ "a,b" -> ("a", "b"), refusing empty names."""
    values = tuple(part.strip() for part in text.split(","))
    if not all(values):
        raise argparse.ArgumentTypeError(
            f"expected comma-separated names, e.g. libero_object,libero_goal; got {text!r}"
        )
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


def finite_float(text: str) -> float:
    """A command-line number that is finite: NaN or infinity would silently change an experiment (a NaN
    threshold never triggers, a NaN weight trains a NaN model)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number")
    return value


def _bare(annotation: Any) -> Any:
    """The annotation without `| None`."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        members = [a for a in typing.get_args(annotation) if a is not type(None)]
        return members[0] if len(members) == 1 else annotation
    return annotation


def _option(annotation: Any) -> tuple[Callable[[str], Any], tuple[Any, ...] | None]:
    """(argparse type, choices) of a field annotation."""
    annotation = _bare(annotation)
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Literal:
        return type(args[0]), args
    if origin in (list, tuple) and args and args[0] is int:
        return int_list, None
    if origin in (list, tuple) and args and args[0] is str:
        return str_list, None
    if annotation is float:
        return finite_float, None
    if annotation in _SCALARS:
        return annotation, None
    raise TypeError(f"no command-line option for a field of type {annotation!r}")


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else None


def _is_config(annotation: Any) -> bool:
    return dataclasses.is_dataclass(_bare(annotation))


def add_settings_arguments(
    parser: argparse.ArgumentParser,
    config_cls: type,
    exclude: tuple[str, ...] = (),
    *,
    show_defaults: bool = True,
    _dest: str = "",
    _prefix: str = "",
) -> None:
    """One option per field of `config_cls` (a dataclass) not in `exclude`, nested configs included.
    `show_defaults`: say each field's default in its help (not where a recipe file supplies the values)."""
    hints = typing.get_type_hints(config_cls)
    for f in dataclasses.fields(config_cls):
        if f.name in exclude:
            continue
        if _is_config(hints[f.name]):
            inner = [name.split(".", 1)[1] for name in exclude if name.startswith(f"{f.name}.")]
            add_settings_arguments(
                parser,
                _bare(hints[f.name]),
                (*f.metadata.get("derived", ()), *inner),
                show_defaults=show_defaults,
                _dest=f"{_dest}{f.name}.",
                _prefix=_prefix + f.metadata.get("prefix", f"{f.name}-"),
            )
        else:
            _add_option(parser, f, hints[f.name], f"{_dest}{f.name}", _prefix, show_defaults)


def _add_option(
    parser: argparse.ArgumentParser, f: dataclasses.Field, annotation: Any, dest: str, prefix: str, show_default: bool
) -> None:
    """The option of one field, stored under `dest` and named `--{prefix}{field-name}` (or its flag); a
    bool is a pair of switches, `--name` and `--no-name`."""
    default, help_text = _default(f), f.metadata.get("help", "").replace("%", "%%")  # argparse formats help with %
    flag = f.metadata.get("flag")
    flag = "--" + prefix + flag.removeprefix("--") if flag else None
    name = prefix + f.name.replace("_", "-")
    if show_default and default is not None:
        shown = ",".join(map(str, default)) if isinstance(default, (list, tuple)) else default
        help_text += f" (default: {shown})"
    if annotation is bool:
        switch = flag or "--" + name
        parser.add_argument(switch, dest=dest, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        return
    kind, choices = (f.metadata["parse"], None) if f.metadata.get("parse") else _option(annotation)
    choices = field_choices(f, annotation) if f.metadata.get("choices") else choices
    parser.add_argument(
        flag or "--" + name,
        dest=dest,
        type=kind,
        choices=choices,
        default=None,
        metavar=f.metadata.get("metavar") or (None if choices else f.name.upper()),
        help=help_text,
    )


def field_choices(f: dataclasses.Field, annotation: Any) -> tuple[Any, ...] | None:
    """The values a field may take: its `choices`, or its `Literal`'s (None: any value of its type)."""
    if f.metadata.get("choices"):
        return tuple(f.metadata["choices"]())
    bare = _bare(annotation)
    return typing.get_args(bare) if typing.get_origin(bare) is Literal else None


def check_choices(config: Any, where: str) -> None:
    """Refuse, in one line, a field of `config` outside its choices (`field_choices`; None passes where the
    field may be None): the one check of every config's named choices, so no config re-checks its own.
    The line reads "unknown {where} {label} ..." with the field's `label` (default: its name)."""
    hints = typing.get_type_hints(type(config))
    for f in dataclasses.fields(config):
        choices, value = field_choices(f, hints[f.name]), getattr(config, f.name)
        if choices is None or value in choices or (value is None and _bare(hints[f.name]) is not hints[f.name]):
            continue
        label = " ".join(filter(None, (where, f.metadata.get("label") or f.name)))
        raise unknown_choice(label, value, choices)


def check_derived(config: Any, where: str) -> None:
    """Refuse a field of a nested config that its owner sets itself (`nested(..., derived=...)`) unless it
    is left at its default: the owner would replace it without a word. `with_overrides` refuses such a
    field when it is given by name; this catches a nested config built with it."""
    for f in dataclasses.fields(config):
        for path in f.metadata.get("derived", ()):
            mine, default = getattr(config, f.name), f.default_factory()
            for name in path.split("."):
                mine, default = getattr(mine, name), getattr(default, name)
            if mine != default:
                raise UserInputError(
                    f"{where}: {f.name}.{path} is set by the {where} itself (it is {mine!r}); leave it at its default"
                )


def settings_from_args(args: argparse.Namespace, config_cls: type, exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of `config_cls` the user set on the command line, nested like the config (options left
    out stay unset)."""
    names = {f.name for f in dataclasses.fields(config_cls)} - set(exclude)
    out: dict[str, Any] = {}
    for dest, value in vars(args).items():
        if value is None or dest.split(".")[0] not in names:
            continue
        *path, name = dest.split(".")
        node = out
        for key in path:
            node = node.setdefault(key, {})
        node[name] = value
    return out


def with_overrides(
    config: Any, overrides: Mapping[str, Any], where: str = "settings", *, _path: str = "", _owned: tuple[str, ...] = ()
) -> Any:
    """`config` with `overrides` (nested like it: {"critic": {"steps": 10}}) replaced. An unknown name, or a
    field the owning config sets itself (`nested(..., derived=...)`), is refused in one line naming it."""
    names = {f.name: f for f in dataclasses.fields(config)}
    hints = typing.get_type_hints(type(config))
    changes = {}
    for key, value in overrides.items():
        if key not in names:
            raise UserInputError(f"{where}: field '{_path}{key}' unknown; expected one of: {', '.join(sorted(names))}")
        if key in _owned:
            raise UserInputError(f"{where}: field '{_path}{key}' is set by the config that holds it; leave it out")
        if _is_config(hints[key]) and isinstance(value, Mapping):
            owned = (
                *names[key].metadata.get("derived", ()),
                *(name.split(".", 1)[1] for name in _owned if name.startswith(f"{key}.")),
            )
            changes[key] = with_overrides(getattr(config, key), value, where, _path=f"{_path}{key}.", _owned=owned)
        else:
            if isinstance(value, float) and not math.isfinite(value):
                raise UserInputError(f"{where}: field '{_path}{key}' is {value}; expected a finite number")
            changes[key] = _coerce(hints[key], value)
    return dataclasses.replace(config, **changes)


def config_from_args(args: argparse.Namespace, config_cls: type, where: str, exclude: tuple[str, ...] = ()) -> Any:
    """The config a command line describes: `config_cls()`'s defaults with the options the user set, built
    (and so validated) before the command does any work, and passed on typed."""
    return with_overrides(config_cls(), settings_from_args(args, config_cls, exclude), where)


def _coerce(annotation: Any, value: Any) -> Any:
    """A sequence in the container its field declares (a list for `list[...]`, a tuple for `tuple[...]`),
    whether it came from YAML, JSON or a caller: configs compare equal to the records they wrote."""
    container = typing.get_origin(_bare(annotation))
    if container in (list, tuple) and isinstance(value, (list, tuple)):
        return container(value)
    return value


def load_config(config_cls: type, path: str | os.PathLike) -> Any:
    """The config a recipe file (YAML, nested like the config) describes: `config_cls()`'s defaults with
    the file's values. A missing file, bad YAML or an unknown field is one line naming the file."""
    import yaml

    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except OSError as e:
        raise UserInputError(f"{path}: cannot read the recipe ({e.strerror})") from None
    except yaml.YAMLError as e:
        raise UserInputError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(data, Mapping):
        raise UserInputError(f"{path}: expected a mapping of settings, got {type(data).__name__}")
    try:
        return with_overrides(config_cls(), data, where=str(path))
    except TypeError as e:
        raise UserInputError(f"{path}: {e}") from None
