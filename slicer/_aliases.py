"""Earlier module paths, kept importable: ``import slicer.slicing`` still works.

The modules moved into folders named after their concepts (docs/development.md lists the
layout). Each earlier path in :data:`MOVED` imports as a thin alias of the module that now
holds its code: its names are read from that module on use (``from slicer.slicing import
slice_skeleton``), so code written against the earlier paths keeps working. New code imports
the new paths.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types

#: earlier module path -> the module that holds its code now
MOVED: dict[str, str] = {
    "slicer.scene_io": "slicer.scene.read",
    "slicer.scene_write": "slicer.scene.write",
    "slicer.scene_3mf": "slicer.scene.threemf",
    "slicer.lattice": "slicer.scene.lattice",
    "slicer.skeleton": "slicer.model.skeleton",
    "slicer.kernel": "slicer.model.siis_kernel",
    "slicer.blend": "slicer.model.blend",
    "slicer.field": "slicer.model.field",
    "slicer.slicing": "slicer.tracer.slicing",
    "slicer.buckets": "slicer.tracer.buckets",
    "slicer.grid": "slicer.tracer.grid",
    "slicer.meshes": "slicer.parts.meshes",
    "slicer.mesh_slicing": "slicer.parts.mesh_slicing",
    "slicer.mesh_intersect": "slicer.parts.mesh_intersect",
    "slicer.part_slicing": "slicer.parts.slicing",
    "slicer.rendering": "slicer.render.rendering",
    "slicer.render_output": "slicer.render.output",
    "slicer.render_parts": "slicer.render.parts",
    "slicer.antialias": "slicer.raster.antialias",
    "slicer.layers": "slicer.raster.placed_layers",
    "slicer.ordering": "slicer.raster.ordering",
    "slicer.tileplan": "slicer.scale.tileplan",
    "slicer.tiles": "slicer.scale.tiles",
    "slicer.tiletask": "slicer.scale.tiletask",
    "slicer.executors": "slicer.scale.executors",
    "slicer.inorder": "slicer.scale.ordered_map",
    "slicer.jobspec": "slicer.job.spec",
    "slicer.config": "slicer.job.config",
    "slicer.checks": "slicer.arguments",
    "slicer.preview": "slicer.viewer.page",
    "slicer.commands": "slicer.cli.commands",
    "slicer.commands.bench": "slicer.cli.commands.bench",
    "slicer.commands.check": "slicer.cli.commands.check",
    "slicer.commands.info": "slicer.cli.commands.info",
    "slicer.commands.lattice": "slicer.cli.commands.lattice",
    "slicer.commands.options": "slicer.cli.commands.options",
    "slicer.commands.preview": "slicer.cli.commands.preview",
    "slicer.commands.printers": "slicer.cli.commands.printers",
    "slicer.commands.render": "slicer.cli.commands.render",
    "slicer.commands.slice": "slicer.cli.commands.slice",
    "slicer.commands.validate": "slicer.cli.commands.validate",
    "slicer._kernels.borrow": "slicer._kernels.runtime.borrow",
    "slicer._kernels.launch": "slicer._kernels.runtime.launch",
    "slicer._kernels.union": "slicer._kernels.field.union",
    "slicer._kernels.points": "slicer._kernels.field.points",
    "slicer._kernels.raysupport": "slicer._kernels.rays.support",
    "slicer._kernels.lazy": "slicer._kernels.rays.lazy",
    "slicer._kernels.union_trace": "slicer._kernels.trace.union",
    "slicer._kernels.binning": "slicer._kernels.field.binning",
    "slicer._kernels.composite": "slicer._kernels.render.composite",
    "slicer._kernels.quadtree": "slicer._kernels.contours.quadtree",
    "slicer._kernels.cellbounds": "slicer._kernels.contours.cellbounds",
    "slicer._kernels.cellstate": "slicer._kernels.contours.cellstate",
    "slicer._kernels.ridgebounds": "slicer._kernels.contours.ridgebounds",
    "slicer._kernels.refine": "slicer._kernels.contours.refine",
    "slicer._kernels.brackets": "slicer._kernels.contours.brackets",
    "slicer._kernels.crossings": "slicer._kernels.contours.crossings",
    "slicer._kernels.coverage": "slicer._kernels.raster.coverage",
    "slicer._kernels.labels": "slicer._kernels.raster.labels",
    "slicer._kernels.order": "slicer._kernels.raster.counting_sort",
    "slicer._kernels.rle": "slicer._kernels.formats.goo_rle",
    "slicer._kernels.islands": "slicer._kernels.formats.islands",
    "formats.printers": "formats.printer_profiles",
}


class _Alias(types.ModuleType):
    """A module object standing for the module named ``target``."""

    def __init__(self, name: str, target: str):
        super().__init__(name)
        self.__dict__["_target"] = target

    def __getattr__(self, name: str):
        return getattr(importlib.import_module(self.__dict__["_target"]), name)

    def __dir__(self):
        return dir(importlib.import_module(self.__dict__["_target"]))


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        return _Alias(spec.name, self.target)

    def exec_module(self, module):
        # a package alias must let its earlier submodules be found through the finder below
        if any(old.startswith(module.__name__ + ".") for old in MOVED):
            module.__path__ = []


class _AliasFinder(importlib.abc.MetaPathFinder):
    """Finds the earlier paths of :data:`MOVED` (and nothing else)."""

    def find_spec(self, fullname, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _AliasLoader(new))


def install() -> None:
    """Put the finder on ``sys.meta_path`` once (idempotent)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.append(_AliasFinder())
