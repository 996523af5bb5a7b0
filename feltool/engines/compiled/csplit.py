"""CasADi's generated C cut into several translation units, compiled on several cores.

A walker's library is one C file of ~15 k lines; ``cc -O2`` spends nearly all of its time per
function (RTL expansion, register allocation, scheduling), so the file's functions are spread
over ``parts`` files compiled at once and linked into one library. Each part holds the file's
header (its helpers and constants under a prefix of its own, so no helper is defined twice), a
declaration of every CasADi function (one shared name each, hidden from the library's
exports) and its share of their definitions; the first part also holds the exported entry
points. The code of every function is CasADi's own, unchanged: only where it is compiled
differs (calls between parts are not inlined, which rounds nothing differently: no option
that lets the compiler reorder floating-point operations is given).
"""

from __future__ import annotations

import re

_FUNCTION = re.compile(
    r"^static int (casadi_f\d+)\(const casadi_real\*\* arg, casadi_real\*\* res, "
    r"casadi_int\* iw, casadi_real\* w, int mem\) \{$")
_SIGNATURE = ("(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, "
              "int mem)")
_HIDDEN = '__attribute__((visibility("hidden")))'


def split_source(text: str, stem: str, parts: int) -> list[str] | None:
    """``text`` (CasADi's C for the library ``stem``) as ``parts`` translation units with about
    equal shares of the functions' lines, or None when it has fewer than two functions or is
    not laid out as this module expects (then it is compiled whole)."""
    lines = text.split("\n")
    prefix = f"  #define CASADI_PREFIX(ID) {stem}_ ## ID"
    if parts < 2 or prefix not in lines:
        return None
    blocks, rest, start, i = [], [], None, 0
    while i < len(lines):
        m = _FUNCTION.match(lines[i])
        if m is None:
            rest.append(lines[i])
            i += 1
            continue
        if start is None:
            start = len(rest) - (1 if rest and rest[-1].startswith("/*") else 0)
        end = lines.index("}", i)
        body = [f"{_HIDDEN} int {m.group(1)}{_SIGNATURE} {{", *lines[i + 1:end + 1], ""]
        blocks.append((m.group(1), body))
        i = end + 1
    if start is None or len(blocks) < 2:
        return None
    header, tail = rest[:start], rest[start:]
    first, others = _shared_zeros(header, stem)
    names = [name for name, _ in blocks]
    shared = [line for name in names
              for line in (f"#undef {name}", f"#define {name} {stem}_{name[len('casadi_'):]}")]
    shared += [f"{_HIDDEN} int {name}{_SIGNATURE};" for name in names]
    share: list[list[str]] = [[] for _ in range(parts)]
    size = [0] * parts
    for _, body in sorted(blocks, key=lambda b: -len(b[1])):  # largest first, to the lightest
        j = size.index(min(size))
        share[j] += body
        size[j] += len(body)
    out = []
    for j in range(parts):
        own = first if j == 0 else _without_exports(
            [f"  #define CASADI_PREFIX(ID) {stem}_p{j}_ ## ID" if line == prefix else line
             for line in others])
        out.append("\n".join(own + shared + share[j] + (tail if j == 0 else ["#ifdef __cplusplus",
                                                                            "} /* extern \"C\" */",
                                                                            "#endif", ""])))
    return out


_ZEROS = re.compile(r"^static const casadi_real casadi_zeros\[(\d+)\] = $")


def _shared_zeros(header: list[str], stem: str) -> tuple[list[str], list[str]]:
    """The first part's header and the others': CasADi's array of zeros (as long as the
    largest argument: 1.6 MB for a walker) defined in the first, declared in the others."""
    for i, line in enumerate(header[:-1]):
        m = _ZEROS.match(line)
        if m and header[i + 1] == "  {0.};":
            head, tail = header[:i] + ["#undef casadi_zeros",
                                       f"#define casadi_zeros {stem}_zeros"], header[i + 2:]
            array = f"{_HIDDEN} const casadi_real casadi_zeros[{m.group(1)}]"
            return head + [array + " = {0.};"] + tail, head + [f"extern {array};"] + tail
    return header, header


def _without_exports(header: list[str]) -> list[str]:
    """The header without its exported definitions (the library's configuration queries: the
    first part defines them)."""
    out, skipping = [], False
    for line in header:
        if skipping:
            skipping = line != "}"
            continue
        if line.startswith("CASADI_SYMBOL_EXPORT"):
            skipping = not line.rstrip().endswith("}")
            continue
        out.append(line)
    return out
