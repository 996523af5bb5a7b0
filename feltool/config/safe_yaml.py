"""YAML read with bounds: size, nesting depth and the number of values after aliases.

PyYAML's ``safe_load`` constructs no objects, but it still follows aliases (a few lines of
``&a [*b, *b, ...]`` -- the "billion laughs" -- expand into 10^9 values that everything after
the loader walks) and composes nested lists recursively (10,000 ``[`` end in a
``RecursionError``). :func:`load_yaml` first walks PyYAML's event stream, which the parser
produces without recursion, counting depth and the values every anchor stands for; only a
document within :data:`~feltool.bounds.MAX_YAML_DEPTH` and
:data:`~feltool.bounds.MAX_YAML_NODES` is then loaded.
"""

from __future__ import annotations

from typing import Any

import yaml

from feltool.bounds import MAX_YAML_DEPTH, MAX_YAML_NODES

#: libyaml's parser when PyYAML has it (the same YAML, ten times faster on a gait's long lists
#: of samples), else PyYAML's own.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class YamlBoundError(ValueError):
    """A YAML document beyond the bounds (its message says which)."""


def check_bounds(text: str, max_depth: int = MAX_YAML_DEPTH,
                 max_nodes: int = MAX_YAML_NODES, loader=None) -> None:
    """Raise :class:`YamlBoundError` when ``text`` nests deeper than ``max_depth`` or stands for
    more than ``max_nodes`` values once its aliases are expanded (also for an alias to a node
    that contains it: a recursive structure). YAML syntax errors are left to the loader."""
    sizes: dict[str, int] = {}        # anchor -> values it stands for
    stack: list[list] = []            # open collections: [count, anchor]
    total = 0

    def add(count: int) -> None:
        nonlocal total
        if stack:
            stack[-1][0] += count
        else:
            total += count
        if total + sum(s[0] for s in stack) > max_nodes:
            raise YamlBoundError(f"more than {max_nodes} values once its aliases (*name) are "
                                 "expanded; an alias bomb? (the limit is feltool's)")

    try:
        for event in yaml.parse(text, Loader=loader or _LOADER):
            if isinstance(event, yaml.ScalarEvent):
                add(1)
                if event.anchor:
                    sizes[event.anchor] = 1
            elif isinstance(event, yaml.AliasEvent):
                if event.anchor not in sizes:
                    raise YamlBoundError(f"the alias *{event.anchor} refers to a node that "
                                         "contains it (a recursive structure) or to no anchor")
                add(sizes[event.anchor])
            elif isinstance(event, yaml.CollectionStartEvent):
                if len(stack) >= max_depth:
                    mark = event.start_mark
                    raise YamlBoundError(f"line {mark.line + 1}: nested deeper than {max_depth} "
                                         "levels (the limit is feltool's)")
                stack.append([1, event.anchor])
            elif isinstance(event, yaml.CollectionEndEvent):
                count, anchor = stack.pop()
                if anchor:
                    sizes[anchor] = count
                add(count)
    except yaml.YAMLError:
        if (loader or _LOADER) is not yaml.SafeLoader:  # libyaml stops at its own limits
            check_bounds(text, max_depth, max_nodes, yaml.SafeLoader)  # (ours, named)
        return  # the loader reports it with its position


def load_yaml(text: str) -> Any:
    """``yaml.safe_load`` of a document within the bounds (:func:`check_bounds`)."""
    check_bounds(text)
    return yaml.load(text, Loader=_LOADER)  # noqa: S506 (a safe loader)

