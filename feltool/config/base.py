"""The schema's base: strict models that name every bad field, and the number types the
sections share (units in each field's description).
"""

from __future__ import annotations

import types
import typing
from collections import Counter
from typing import Annotated, Any, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
)

from feltool.bounds import (
    MAX_ABS_GRAVITY,
    MAX_ANGLE,
    MAX_LENGTH,
)

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]


NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]


FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


Angle = Annotated[float, Field(ge=-MAX_ANGLE, le=MAX_ANGLE, allow_inf_nan=False)]


Length = Annotated[float, Field(ge=-MAX_LENGTH, le=MAX_LENGTH, allow_inf_nan=False)]


Gravity = Annotated[float, Field(ge=-MAX_ABS_GRAVITY, le=MAX_ABS_GRAVITY, allow_inf_nan=False)]


def _numeric(tp: Any) -> bool:
    """Whether a field type would read a YAML boolean as the number 1 or 0."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Annotated:
        return _numeric(args[0])
    if origin in (Union, types.UnionType):
        return any(_numeric(a) for a in args) and bool not in args
    return tp in (int, float)


def _bool_in(tp: Any, value: Any) -> str | None:
    """Where a boolean sits in ``value`` that the type ``tp`` would read as a number ("" for
    the value itself, ".2" for an item of a list), or None. Nested models check their own."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Annotated:
        return _bool_in(args[0], value)
    if isinstance(value, bool):
        return "" if _numeric(tp) else None
    if origin in (Union, types.UnionType):
        return next((w for a in args if (w := _bool_in(a, value)) is not None), None)
    if isinstance(value, list | tuple) and origin in (list, tuple) and args:
        for i, item in enumerate(value):
            item_tp = args[0] if origin is list or args[-1] is Ellipsis else \
                args[i] if i < len(args) else Any
            where = _bool_in(item_tp, item)
            if where is not None:
                return f".{i}{where}"
    if isinstance(value, dict) and origin is dict and len(args) == 2:
        for key, item in value.items():
            where = _bool_in(args[1], item)
            if where is not None:
                return f".{key}{where}"
    return None


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    @field_validator("*", mode="before")
    @classmethod
    def _booleans_are_not_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        """YAML reads yes/no/on/off/true/false as booleans, and pydantic would take a boolean
        for the number 1 or 0 (``cycles: yes`` would run one cycle): refuse them wherever a
        number is expected."""
        field = cls.model_fields.get(info.field_name)
        if field is None:
            return value
        where = _bool_in(field.annotation, value)
        if where is not None:
            item = f" (item {where.lstrip('.')})" if where else ""
            raise ValueError(f"a boolean (yes/no/true/false/on/off){item} is not a number; "
                             "write the number")
        return value


Vector3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


def once_each(seeds: Any) -> Any:
    """``seeds`` unchanged; a list naming a seed twice is refused (a repeat would be the same
    run again). For a ``seeds`` field validator."""
    if isinstance(seeds, list):
        repeated = sorted(x for x, n in Counter(seeds).items() if n > 1)
        if repeated:
            raise ValueError(f"seed {', '.join(map(str, repeated))} given more than once; "
                             "each seed runs once (a repeat would be the same run again)")
    return seeds
