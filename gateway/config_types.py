"""Config vocabulary shared by the gateway and the simulator.

Ranged integers, strict models, reading text/YAML files, and turning a pydantic error into
one line that names the YAML path, the value and the rule
(``axes.X.registers.target.address: 70000 is not in 0..65535``). The simulator shares this
vocabulary on purpose: one spelling of a register address for both configs.
"""

from __future__ import annotations

import difflib
import re
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError


def in_range(lo: int, hi: int) -> AfterValidator:
    """Validator: an integer in ``lo..hi`` (message ``is not in lo..hi``)."""

    def check(value: int) -> int:
        if not lo <= value <= hi:
            raise ValueError(f"is not in {lo}..{hi}")
        return value

    return AfterValidator(check)


def _greater_than_zero(value: float) -> float:
    if not value > 0:
        raise ValueError("must be > 0")
    return value


def _low_below_high(value: tuple[float, float]) -> tuple[float, float]:
    if not value[0] < value[1]:
        raise ValueError(f"[{value[0]:g}, {value[1]:g}] must be [low, high] with low < high")
    return value


Address = Annotated[int, in_range(0, 0xFFFF)]
Word = Annotated[int, in_range(0, 0xFFFF)]
Port = Annotated[int, in_range(0, 65535)]
UnitId = Annotated[int, in_range(1, 247)]
Bit = Annotated[int, in_range(0, 15)]
Positive = Annotated[float, AfterValidator(_greater_than_zero)]
PositiveFloat = Annotated[float, Field(gt=0)]
NonNegFloat = Annotated[float, Field(ge=0)]
Interval = Annotated[tuple[float, float], AfterValidator(_low_below_high)]  # [low, high]
WordOrder = Literal["hi_lo", "lo_hi"]


def path_error(path: tuple[Any, ...], value: Any, rule: str) -> ValueError:
    """A model-level error that names the key it is about (see format_validation_error)."""
    return ValueError(f"{'.'.join(str(p) for p in path)}: {value!r} {rule}")


class StrictModel(BaseModel):
    """Unknown keys are errors; a loaded config never changes."""

    model_config = ConfigDict(extra="forbid", frozen=True)


_RELATIVE_PATH = re.compile(r"[\w.]+")


def format_validation_error(exc: ValidationError, union_tags: frozenset[str] = frozenset(),
                            root: type[BaseModel] | None = None) -> str:
    """One line for a validation error: ``yaml.path: value rule`` (the first of
    :func:`validation_lines`)."""
    return validation_lines(exc, union_tags, root)[0]


def validation_lines(exc: ValidationError, union_tags: frozenset[str] = frozenset(),
                     root: type[BaseModel] | None = None) -> list[str]:
    """Every mistake of a validation error, one line each, the deepest first:
    ``yaml.path: value rule``.

    In a union, the member that got furthest explains the mistake best (the others'
    errors, on a path that leads to it, are left out); ``union_tags`` are the member names
    pydantic puts into the path, removed here. A model-level rule may name the key it is
    about as ``"relative.path: rest"``; that path is appended to the location. An unknown
    key is given the nearest known one of its model (``root``: the top model) as a guess.
    """

    def clean(loc: tuple[Any, ...]) -> tuple[Any, ...]:
        return tuple(p for p in loc if not (isinstance(p, str) and p in union_tags))

    errors = exc.errors(include_url=False)
    ordered = sorted(errors, key=lambda e: -len(clean(e["loc"])))
    taken: list[tuple[Any, ...]] = []
    lines: list[str] = []
    explained = set()  # a misspelt required key: its stray spelling is said beside it
    for err in errors:
        if err["type"] == "missing":
            loc = clean(err["loc"])
            stray = [clean(e["loc"]) for e in errors if e["type"] == "extra_forbidden"
                     and clean(e["loc"])[:-1] == loc[:-1]]
            near = difflib.get_close_matches(str(loc[-1]), [str(x[-1]) for x in stray], n=1)
            explained.update(x for x in stray if near and str(x[-1]) == near[0])
    for err in ordered:
        loc = clean(err["loc"])
        if any(loc == t[: len(loc)] for t in taken) or loc in explained:
            continue
        taken.append(loc)
        line = _one_line(err, loc, errors, clean, root)
        if line not in lines:
            lines.append(line)
    return lines or ["(no detail)"]


def _one_line(err: Any, loc_parts: tuple[Any, ...], errors: list[Any], clean: Any,
              root: type[BaseModel] | None) -> str:  # fmt: skip
    loc = ".".join(str(p) for p in loc_parts)
    message = str(err["msg"]).removeprefix("Value error, ")
    if err["type"] == "missing":
        parent = loc_parts[:-1]
        stray = [str(clean(e["loc"])[-1]) for e in errors
                 if e["type"] == "extra_forbidden" and clean(e["loc"])[:-1] == parent]
        near = difflib.get_close_matches(str(loc_parts[-1]), stray, n=1)
        return f"{loc}: missing (required)" + (f"; {near[0]!r} beside it is no key (a typo?)"
                                                if near else "")  # fmt: skip
    if err["type"] == "extra_forbidden":
        known = _keys_at(root, loc_parts[:-1]) if root is not None else []
        near = difflib.get_close_matches(str(loc_parts[-1]), known, n=1)
        return f"{loc}: unknown key" + (f" (did you mean {near[0]!r}?)" if near else "")
    value = err.get("input")
    if isinstance(value, dict | list | tuple):
        head, sep, rest = message.partition(": ")
        if sep and _RELATIVE_PATH.fullmatch(head):
            return f"{loc}.{head}: {rest}" if loc else f"{head}: {rest}"
        return f"{loc or '(top level)'}: {message}"
    if message.startswith(("is ", "must ")):
        return f"{loc}: {value!r} {message}"
    return f"{loc}: {value!r}: {message[:1].lower()}{message[1:]}"


def _keys_at(model: type[BaseModel], path: tuple[Any, ...]) -> list[str]:
    """The keys of the model found at ``path`` from ``model`` (through nested models,
    mappings and lists); [] where the path leads to no model."""
    current: Any = model
    for part in path:
        current = _model_in(current)
        if current is None:
            return []
        if isinstance(current, tuple):  # a mapping or list: its keys are the user's
            current = current[0]
            continue
        field = current.model_fields.get(str(part))
        if field is None:
            return []
        current = field.annotation
    found = _model_in(current)
    if isinstance(found, tuple):
        found = found[0]
    return list(found.model_fields) if isinstance(found, type) and issubclass(found, BaseModel) \
        else []  # fmt: skip


def _model_in(tp: Any) -> Any:
    """The model in an annotation: a model class, or (model,) for a dict/list of models."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return tp
    origin = get_origin(tp)
    args = [a for a in get_args(tp) if a is not type(None)]
    if origin in (dict, list, tuple, set, frozenset) and args:
        inner = _model_in(args[-1])
        if inner is not None:
            return (inner if not isinstance(inner, tuple) else inner[0],)
        return None
    for arg in args:  # Optional, Union, Annotated
        inner = _model_in(arg)
        if inner is not None:
            return inner
    return None


def read_text(path: str | Path, error: type[Exception]) -> str:
    """A UTF-8 text file, or ``error`` with one line naming the file and what went wrong."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a UTF-8 text file ({exc.reason})") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None


#: PyYAML's safe loader in C where the wheel has libyaml (7x faster on a config: every start,
#: every reload, every commissioning step pays it), else the same loader in Python
_BASE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class UniqueKeyLoader(_BASE_LOADER):  # type: ignore[misc,valid-type]
    """The safe loader, refusing a key given twice in one mapping (YAML forbids it;
    PyYAML keeps the last silently, so a second ``X:`` axis would replace the first)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:  # type: ignore[type-arg]
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                first = seen.get(key)
            except TypeError:  # unhashable: the base class says so
                continue
            if first is not None:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice (first on line {first + 1})",
                    key_node.start_mark)  # fmt: skip
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)  # type: ignore[no-any-return]


SAFE_LOADER = UniqueKeyLoader


def read_yaml(path: str | Path, error: type[Exception]) -> Any:
    """Parsed YAML of a file, or ``error`` naming the file and the line of a syntax error."""
    text = read_text(path, error)
    try:
        return yaml.load(text, Loader=SAFE_LOADER)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{path}: {where}not valid YAML ({problem})") from None
