"""``o3d-ofp transfer``: move a signal (colors, a texture, coordinates, any array) to a target."""

from __future__ import annotations

import argparse
import logging
import os

from ..boundary import texture as tex
from ..boundary.bake import transfer_texture
from ..boundary.convert import vertex_colors
from ..boundary.io import read_geometry, write_geometry
from ..core.texture import MAX_TEXTURE_SIZE, TEXTURE_SIZE
from ..core.wording import Said
from ..workflows.pipeline import carry, pull_back
from . import _common as common
from ._common import GEOMETRY_OUT, bounded_int, report, stage
from ._pair import Pair, add_pair_options, map_name, plan, prepare_pair, read_pair

__all__ = ["add_parser", "run"]

logger = logging.getLogger(__name__)

_BAKED = (".obj", ".glb", ".gltf")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("transfer", help="transfer a signal from a source to a target shape")
    add_pair_options(p, preset="ours", several=True)
    a = p.add_argument
    a("--signal", help="colors, texture (as vertex colors), xyz or FILE.npy; default: the source's "
      "texture (or vertex colors) baked into a target's UVs for an .obj/.glb/.gltf output, else "
      "its colors on the target's vertices; with several targets, colors or texture")
    a("--texture", help="the source's texture image, for a bake or --signal texture (default: the "
      "one its material names)")
    a("--via-basis", action="store_true", help="a closest map's values through the OFP bases "
      "(smoother where the map is noisy) instead of the exact pull-back")
    a("--pull-back", action="store_true", help="an estimated or given map's values pulled back "
      "with no OFP basis (sharper where the map is right; a closest map's default)")
    a("--uv-atlas", action="store_true", help="a target WITHOUT UVs gets a new UV atlas (Open3D's "
      "compute_uvatlas) the colors are baked into (output .obj/.glb/.gltf)")
    a("--texture-size", type=bounded_int(1, MAX_TEXTURE_SIZE), help="side of a baked texture in "
      f"pixels ({TEXTURE_SIZE}; at most {MAX_TEXTURE_SIZE})")
    a("-o", "--output", required=True, help="colored target (mesh/cloud), or .npy values; with "
      "several targets a folder")  # fmt: skip
    common.add_collection_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read, make (or read) the map, transfer, write (for each target)."""
    common.refuse((args.texture is not None and not os.path.isfile(args.texture),
                   f"--texture {args.texture}: no such image file"))  # fmt: skip
    if not common.single(args, "target"):
        return _run_many(args)
    common.refuse(
        (args.uv_atlas and (args.signal is not None or not args.output.lower().endswith(_BAKED)),
         "--uv-atlas bakes the source's colors into a new atlas: it needs an .obj/.glb/.gltf "
         "output (-o) and no --signal"),
        (args.via_basis and args.pull_back, "--via-basis transfers through the OFP bases and "
         "--pull-back without them: give one of them"),
        (args.via_basis and args.uv_atlas, "--via-basis sends the colors to the target's vertices "
         "and --uv-atlas bakes them into a new atlas: give one of them"),
    )  # fmt: skip
    pair = read_pair(args, (*GEOMETRY_OUT, ".npy"))
    closest = args.map == "closest" or getattr(pair.given, "method", None) == "closest"
    common.refuse((args.via_basis and not closest, "--via-basis applies to a closest map (--map "
                   "closest or its saved map): other maps go through the OFP bases already"))
    # a bake: a source mesh with a texture or (without UVs) vertex colors onto a mesh target
    # with UVs (or an atlas), written as OBJ/glTF
    colored = tex.has_uvs(pair.source) or vertex_colors(pair.source) is not None
    if args.signal is None and pair.F1 is not None and pair.F2 is not None and colored and (
            args.uv_atlas or tex.has_uvs(pair.target)) and args.output.lower().endswith(_BAKED):
        if args.uv_atlas and tex.has_uvs(pair.target):
            logger.warning("%s has its own UVs: the texture is baked into them (--uv-atlas makes "
                           "an atlas for a target without UVs only)", args.target)  # fmt: skip
        return _bake(args, pair, closest)
    common.refuse(
        (args.texture_size is not None, "--texture-size applies to a bake (a textured or "
         "vertex-colored source mesh onto a mesh target with UVs, or --uv-atlas, written as "
         ".obj/.glb/.gltf); here the colors go to the vertices"),
        (args.uv_atlas, "--uv-atlas needs a source mesh with a texture or vertex colors, a mesh "
         "target and an .obj/.glb/.gltf output"),
    )  # fmt: skip
    # default: the colors, or the texture of a textured source without vertex colors (as vertex
    # colors: a target without UVs, or an output that cannot hold a texture)
    textured = vertex_colors(pair.source) is None and tex.has_uvs(pair.source)
    spec = args.signal or ("texture" if textured else "colors")
    if args.signal is None and textured and tex.has_texture_image(pair.source):  # (else asked)
        logger.info("the source has a texture and no vertex colors: its texture is transferred")
    if spec in ("colors", "texture"):  # refused before the warnings below (which contradicted)
        common.check_colors_output(args.output)
    _warn_lost_texture(args, pair, spec)
    f, kind = common.read_signal(pair.source, pair.V1, args.source, spec, args.texture, args.output)
    why = ("the closest map's values are pulled back exactly, with no OFP basis; drop it, or add "
           "--via-basis to transfer through the bases")  # fmt: skip
    if args.pull_back:
        why = ("--pull-back carries the values through the map with no OFP basis; drop it, or "
               + ("replace --pull-back by --via-basis" if closest else "drop --pull-back")
               + " to transfer through the bases")  # fmt: skip
    via_basis = True if args.via_basis else False if args.pull_back else None
    planned = plan(args, pair, "colors", files=True, via_basis=via_basis,
                   unused=lambda named: f"{'/'.join(named)} does not apply here: {why}")
    prepared = prepare_pair(args, pair, planned)
    corr, name = prepared.correspondence, map_name(args, prepared.correspondence)
    surface = corr.barycentric_21 is not None
    with stage("transfer" if not planned.exact else "pull-back through the surface map" if surface
               else "pull-back"):  # fmt: skip
        if not planned.exact:
            g = carry(f, planned, prepared)
        elif spec == "texture" and surface:  # the texture itself at the surface point, not the
            # source's per-vertex samples interpolated there (blurrier)
            image = tex.mesh_texture(pair.source, args.texture)
            g = image.sample(corr.faces_21, corr.barycentric_21)
        else:
            g = pull_back(f, corr, pair.F1)
    how = (f"{'exact ' * closest}pull-back" if planned.exact else
           f"{prepared.bases[0].size} -> {prepared.bases[1].size} basis functions")  # fmt: skip
    # positions sent to the target are written in its own units, as a detail is
    g = g / (pair.target_scale or 1.0) if kind == "xyz" else g
    written = common.write_result(args.output, pair.own_target, g, kind, pair.inputs)
    report([f"{args.source} -> {args.target}: {how}, map {name}", "wrote " + ", ".join(written)])
    return 0


def _warn_lost_texture(args: argparse.Namespace, pair: Pair, spec: str) -> None:
    """Warn when the target's UVs or texture are not written with the colors sent to it."""
    if pair.F2 is None or not tex.has_uvs(pair.target):
        return
    if pair.F1 is None:
        logger.warning("%s is a point cloud: its colors go to the vertices of %s (a cloud has no "
                       "surface to bake from) and the file written has no texture", args.source,
                       args.target)  # fmt: skip
    elif args.signal in ("colors", "texture"):
        own = "the source's texture" if tex.has_uvs(pair.source) else "them"
        logger.warning("%s has UVs: --signal %s puts the source's colors on its vertices (blurrier)"
                       " and the file written has no texture; leave out --signal to bake %s into "
                       "its UV layout (output .obj/.glb/.gltf)", args.target, args.signal, own)
    elif args.signal is None and spec in ("colors", "texture"):
        what = "texture goes" if spec == "texture" else "vertex colors go"
        logger.warning("%s has UVs, but %s cannot hold a texture: the source's %s to the target's "
                       "vertex colors (blurrier) and the target's UVs are not written; write "
                       ".obj/.glb/.gltf to bake them into the target's UVs", args.target,
                       args.output, what)  # fmt: skip


def _run_many(args: argparse.Namespace) -> int:
    """One source onto many targets: colors, or the texture baked into each target's UVs.

    A source colored per vertex is baked when ``--texture-size`` or ``--uv-atlas`` asks for it;
    otherwise its colors go to the targets' vertices, in the targets' own formats (a target's
    texture image is then not written, with a warning in its record).
    """
    common.refuse((args.signal not in (None, "colors", "texture"),
                   f"--signal {args.signal}: with several targets the signal is colors or texture"))
    kind, why = "colors", f"--signal {args.signal} sends the colors to the targets' vertices"
    if args.signal is None:  # a textured source is baked into the targets' own UV layouts, as
        try:  # for one target; one colored per vertex when --texture-size or --uv-atlas asks
            surface = tex.surface_colors(read_geometry(args.source), args.texture)
            asked = args.texture_size is not None or args.uv_atlas
            kind = "texture" if asked or isinstance(surface, tex.MeshTexture) else "colors"
            why = f"{args.source} has no texture coordinates (UVs)"
        except (TypeError, ValueError, FileNotFoundError) as exc:
            why = tex.no_texture_message(args.source, exc)
    common.refuse((kind != "texture" and args.texture_size is not None, Said(
        "--texture-size applies to a bake, and nothing is baked here: {why}", {"why": why})))
    return common.run_transfers(args, kind=kind, options={
        "signal": args.signal or "auto", "texture_size": args.texture_size,
        "atlas": args.uv_atlas, "texture": args.texture})  # fmt: skip


def _bake(args: argparse.Namespace, pair: Pair, closest: bool) -> int:
    """Bake the source's texture (or vertex colors) into the target's UV layout and write it."""
    common.refuse(
        (args.via_basis, "--via-basis sends colors through the OFP bases to the target's vertices; "
         "a bake reads the source through the map: add --signal colors, or drop --via-basis"),
        (args.pull_back, "--pull-back puts values on the target's vertices; a bake reads the "
         "source's colors through the map with no OFP basis already: drop --pull-back, or add "
         "--signal colors for per-vertex colors"),
    )  # fmt: skip
    instead = (f", or add --signal colors{' --via-basis' * closest} to transfer the colors to the "
               "target's vertices through the bases") if not args.uv_atlas else ""  # fmt: skip
    planned = plan(args, pair, "texture", unused=lambda named: (
        f"{'/'.join(named)} does not apply here: a bake reads the source's colors through the "
        f"map, with no OFP basis; drop it{instead}"))  # fmt: skip
    try:  # a bake whose colors cannot be read is refused before any work (named: file or flag)
        tex.surface_colors(pair.source, args.texture)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        raise common.texture_error(args.source, args.texture, exc) from exc
    corr = prepare_pair(args, pair, planned).correspondence
    size = args.texture_size or TEXTURE_SIZE
    with stage(f"texture bake ({size} x {size})"):
        out = transfer_texture(pair.source, pair.target, correspondence=corr, size=size,
                               texture=args.texture, atlas=args.uv_atlas)  # fmt: skip
    write_geometry(args.output, pair.in_target_units(out), protect=pair.inputs)
    layout = "new UV atlas" if args.uv_atlas and not tex.has_uvs(pair.target) else "UV layout"
    what = "texture" if tex.has_uvs(pair.source) else "vertex colors"
    report([f"{args.source} -> {args.target}: {what} baked in the target's {layout} ({size} px), "
            f"map {map_name(args, corr)}",
            f"wrote {args.output} (with its material and texture image)"])  # fmt: skip
    return 0
