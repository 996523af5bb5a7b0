"""yourdfpy without paying for trimesh until a mesh is needed.

yourdfpy imports trimesh (with SciPy, networkx, ...: a third of a second, most of ``feltool``'s
start-up) at its top, but feltool only parses and validates URDF text with it (no scene graph,
no meshes loaded), which needs trimesh's small ``transformations`` module alone. :data:`yourdfpy`
is the real yourdfpy, imported with ``trimesh`` standing in as the real package whose
``__init__`` runs on first use of any other of its attributes (its submodules import normally).
When trimesh is already imported, nothing is deferred.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types


class _DeferredPackage(types.ModuleType):
    """The trimesh package before its ``__init__`` ran: any attribute not yet set runs it."""

    _annotations_only = ("Trimesh", "Scene")  # used by yourdfpy's signatures at import time
    _importing = False

    def __getattr__(self, name: str):
        if _DeferredPackage._importing and name in self._annotations_only:
            return object
        if name.startswith("__"):
            raise AttributeError(name)
        spec = self.__spec__
        self.__class__ = types.ModuleType  # from now on an ordinary module
        spec.loader.exec_module(self)
        return getattr(self, name)


def _import_yourdfpy():
    if "trimesh" in sys.modules or "yourdfpy" in sys.modules:
        return importlib.import_module("yourdfpy")
    spec = importlib.util.find_spec("trimesh")
    if spec is None or spec.loader is None or spec.submodule_search_locations is None:
        return importlib.import_module("yourdfpy")  # (yourdfpy says what is missing)
    stub = _DeferredPackage("trimesh")
    stub.__spec__, stub.__file__ = spec, spec.origin
    stub.__path__, stub.__package__ = list(spec.submodule_search_locations), "trimesh"
    stub.__loader__ = spec.loader
    sys.modules["trimesh"] = stub
    _DeferredPackage._importing = True
    try:
        return importlib.import_module("yourdfpy")
    except BaseException:
        sys.modules.pop("trimesh", None)
        raise
    finally:
        _DeferredPackage._importing = False


yourdfpy = _import_yourdfpy()
