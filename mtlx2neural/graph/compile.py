"""Compile a MaterialX material into a folded, pruned BSDF program plus its spatial sub-graph."""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field

import MaterialX as mx

from mtlx2neural.errors import InputError
from mtlx2neural.graph.bsdf_program import CLOSURE_NODES, BsdfProgram, build_program
from mtlx2neural.graph.evaluator import GraphEvaluator
from mtlx2neural.graph.expand import expand_material
from mtlx2neural.graph.geometry import geometry_reads
from mtlx2neural.graph.ir import Const, Input, IRGraph, Ref
from mtlx2neural.graph.ops import OPS, Application, bake_application
from mtlx2neural.graph.spatial import (
    FRAME_AXES,
    SPATIAL,
    UV_PRIMVARS,
    needs_conversion,
    texture,
    texture_colorspaces,
)
from mtlx2neural.graph.surface_terms import SurfaceTerms, constant_terms, surface_terms
from mtlx2neural.graph.validate import check_image_modes
from mtlx2neural.imaging.resolve import resolve_case

NATIVE = set(OPS) | CLOSURE_NODES | SPATIAL | set(FRAME_AXES)


@dataclass
class CompiledMaterial:
    """Everything the reference needs: IR, folded constants, BSDF program, spatial nodes."""

    name: str
    source: str
    graph: IRGraph
    evaluator: GraphEvaluator
    program: BsdfProgram
    spatial_nodes: list[int]
    case_fixes: list[str] = field(default_factory=list)
    """Warnings for texture paths read with another case (:func:`mtlx2neural.imaging.resolve.resolve_case`)."""
    application: Application = field(default_factory=Application)
    """The instant ``time`` and ``frame`` nodes folded to (:class:`~mtlx2neural.graph.ops.Application`)."""
    reads_application: list[str] = field(default_factory=list)
    """The application nodes the graph reads (``time``, ``frame``): then baked at ``application``."""
    surface: SurfaceTerms = field(default_factory=SurfaceTerms)
    """Emission and opacity beside the BSDF (:mod:`mtlx2neural.graph.surface_terms`)."""
    surface_nodes: list[int] = field(default_factory=list)
    """Spatial nodes the emission and opacity read (not the BSDF's), in topological order."""
    _parameters: list | None = field(default=None, repr=False)

    @property
    def all_spatial_nodes(self) -> list[int]:
        """Spatial nodes of the BSDF, emission and opacity together (topological order): every texture read."""
        return sorted(set(self.spatial_nodes) | set(self.surface_nodes))

    def parameters(self) -> list[tuple[str, Input, str]]:
        """Every run-time parameter of the BSDF program: (name, IR input, MaterialX type).

        Names are "<lobe node path>.<input>" for lobe parameters and
        "<combinator node path>.<mix|in2|opacity>" for mix amounts and tints; the
        reference accepts the same names as overrides (``params=``).
        """
        if self._parameters is not None:  # the program is fixed after compilation
            return self._parameters
        out = []
        for leaf in self.program.leaves():
            nd_inputs = self.graph[leaf.node].inputs
            for name, inp in nd_inputs.items():
                mx_type = inp.type if isinstance(inp, Const) else self.graph.output_type(inp)
                out.append((f"{leaf.path}.{name}", inp, mx_type))
        for key, inp in self.program.amounts():
            mx_type = inp.type if isinstance(inp, Const) else self.graph.output_type(inp)
            out.append((key, inp, mx_type))
        self._parameters = out
        return out

    def refresh_spatial(self) -> None:
        """Recompute :attr:`spatial_nodes` after the evaluator's classification changed
        (:meth:`~mtlx2neural.graph.evaluator.GraphEvaluator.fix_object_to_world`)."""
        needed = list(self.program.inputs())
        for leaf in self.program.leaves():
            needed += list(self.graph[leaf.node].inputs.values())
        self.spatial_nodes = self.evaluator.spatial_closure(needed)
        self.surface_nodes = self.evaluator.spatial_closure(self.surface.inputs())

    def varying_parameters(self) -> list[tuple[str, Input, str]]:
        """The parameters that depend on the spatial sub-graph (texture coordinates, images...)."""
        return [(k, i, t) for k, i, t in self.parameters() if isinstance(i, Ref) and self.evaluator.spatial[i.node]]

    def describe(self) -> dict:
        """Lobes kept/pruned, approximations, spatial inputs, textures and the geometric inputs the graph
        reads with their source (``geometry_inputs``: node, kind, space or primvar, source) (JSON-friendly)."""
        g = self.graph
        textures, spatial_inputs, notes = [], [], []
        for i in self.all_spatial_nodes:
            n = g[i]
            if n.category == "image":
                f = n.inputs.get("file")
                cs, working = texture_colorspaces(n)
                if n.type not in ("color3", "color4"):
                    cs = "raw"  # data textures (normals, roughness, masks) are never converted
                textures.append({"node": n.path, "file": f.value if isinstance(f, Const) else None,
                                 "colorspace": cs or "raw", "working_space": working,
                                 "converted": needs_conversion(cs, working)})
            elif n.category in SPATIAL or self.evaluator.world_transform[i]:
                spatial_inputs.append({"node": n.path, "kind": n.category})
                gp = n.inputs.get("geomprop")
                if (n.category == "geompropvalue" and isinstance(gp, Const) and gp.value not in UV_PRIMVARS
                        and self.evaluator.geometry is None):
                    notes.append(f"'{n.path}' reads primvar '{gp.value}', which a baked material cannot vary: "
                                 f"its default value is used")
        varying = [k for k, _, _ in self.varying_parameters()]
        geo = self.evaluator.geometry
        where = geo.describe() if geo is not None else "not bound: position (u, v, 0), the frame's axes, defaults"
        geometry_inputs = [{**r, "source": where} for r in geometry_reads(g, self.spatial_nodes, self.evaluator.frame_bound)]
        return {
            "material": self.name,
            "source": self.source,
            "lobes_kept": list(self.program.kept),
            "lobes_pruned": list(self.program.pruned),
            "approximations": (list(self.program.notes) + notes + list(self.surface.refused)
                               + list(self.surface.approximated)),
            "surface": self.describe_surface(),
            "spatial_inputs": spatial_inputs,
            "textures": textures,
            "varying_parameters": varying,
            "geometry_inputs": geometry_inputs,
            "ir_nodes": len(g.nodes),
        }


    def describe_surface(self) -> dict:
        """``{"emission": "none" | "constant" | "textured", "opacity": ..., "refused": [...]}``: what the
        material emits and covers besides its BSDF, and the direction-dependent EDFs left out."""
        ev, terms = self.evaluator, self.surface

        def kind(ts):
            if not ts:
                return "none"
            return "constant" if constant_terms(ev, ts) else "textured"
        return {"emission": kind(terms.emission), "opacity": kind(terms.opacity), "refused": list(terms.refused)}


FILE_READERS = ("image", "hextiledimage", "hextilednormalmap")
"""Categories whose ``file`` input is read when the material is compiled: a missing file is an error
(or, with ``allow_missing_textures``, the node's default) and a file named with another case is found."""


def compile_material(document: mx.Document, material: str | None = None, device="cpu",
                     allow_missing_textures: bool = False, strict_case: bool = False,
                     application: Application | None = None) -> CompiledMaterial:
    """Expand, fold and prune ``material`` of ``document`` (a MaterialX document without libraries).

    ``time`` and ``frame`` nodes fold to ``application``'s instant (None: frame 1 at 24 fps, time
    1/24 s; :class:`~mtlx2neural.graph.ops.Application`); a graph that reads them gets a note naming
    the frame and time it was baked at.

    A missing texture is an error naming the file and node, unless
    ``allow_missing_textures``: then its image node returns its declared ``default``.
    A texture path that does not exist but matches one file when case is ignored reads that
    file, with a warning in ``case_fixes`` and the notes (``strict_case``: an error instead;
    :func:`mtlx2neural.imaging.resolve.resolve_case`).
    """
    graph, root, source, notes = expand_material(document, material, NATIVE)
    application = application or Application()
    reads = bake_application(graph, application)  # before the evaluator folds the constants
    ev = GraphEvaluator(graph, source, device=device)
    program = build_program(ev, root)
    program.notes += notes
    needed = list(program.inputs())
    for leaf in program.leaves():
        needed += list(graph[leaf.node].inputs.values())
    spatial_nodes = ev.spatial_closure(needed)
    surface = surface_terms(ev, root)
    surface_nodes = ev.spatial_closure(surface.inputs())
    check_image_modes(source, graph, sorted(set(spatial_nodes) | set(surface_nodes)))  # before any texture is read
    name = material or next(n.getName() for n in document.getMaterialNodes())
    case_fixes = []
    for i in sorted(set(spatial_nodes) | set(surface_nodes)):
        n = graph[i]
        f = n.inputs.get("file")
        if n.category in FILE_READERS and isinstance(f, Const) and f.value:
            try:
                found, fixed = resolve_case(f.value, node=n.path, strict=strict_case)
                if fixed:
                    warnings.warn(f"{source}: {fixed}", stacklevel=2)
                    case_fixes.append(fixed)
                    program.notes.append(fixed)
                    n.inputs["file"] = f = dataclasses.replace(f, value=found)
                texture(f.value, n.path)  # reads (and caches) the file now: errors surface at load time
            except InputError as exc:
                if not allow_missing_textures:
                    raise InputError(f"{source}: {exc} Pass --allow-missing-textures to use the node's "
                                     f"declared default instead.", node=n.path) from exc
                n.attrs["missing"] = "1"
                program.notes.append(f"texture '{f.value}' of '{n.path}' is missing: its declared default is used")
    if reads:
        program.notes.append(application_note(name, reads, application))
    return CompiledMaterial(name, source, graph, ev, program, spatial_nodes, case_fixes=case_fixes,
                            application=application, reads_application=reads, surface=surface,
                            surface_nodes=surface_nodes)


def application_note(material: str, reads: list[str], application: Application) -> str:
    """The note of a material whose graph reads ``time``/``frame`` (``reads``): the instant it is baked at."""
    nodes = " and ".join(f"`{r}`" for r in reads)
    return (f"material {material} reads {nodes}: baked at frame {application.frame:g} "
            f"(time {application.time:g} s at {application.fps:g} fps); set --frame (and --fps)")
