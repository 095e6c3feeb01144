"""``o3d-ofp transfer``: move a signal (colors, a texture, coordinates, any array) to a target."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
from collections.abc import Iterator
from typing import Any

from ..core.texture import MAX_TEXTURE_SIZE, TEXTURE_SIZE
from ._common import (
    CLOUD_OUT,
    MESH_OUT,
    UsageError,
    check_output,
    check_output_kind,
    report,
    stage,
)
from ._many import (
    PAIR_ONLY,
    add_collection_options,
    check_single,
    is_collection,
    refuse_flags,
    run_transfers,
)
from ._pair import (
    add_pair_options,
    bases_for_pair,
    estimate_or_use_map,
    map_first,
    read_pair,
)
from ._signal import (
    check_colors_output,
    read_signal,
    signal_sides,
    texture_error,
    write_result,
)
from ._types import bounded_int

__all__ = ["add_parser", "run"]

logger = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("transfer", help="transfer a signal from a source to a target shape")
    add_pair_options(p, preset="ours", several=True)
    p.add_argument(
        "--signal",
        help="colors, texture (as vertex colors), xyz or FILE.npy of the source; default: the "
        "source's texture (or, for a source without UVs, its vertex colors) baked into the "
        "target's own UV layout when the target has UVs and the output is .obj/.glb/.gltf, "
        "else its colors on the target's vertices",
    )
    p.add_argument(
        "--texture", help="the source's texture image, for a bake or --signal texture (default: "
        "the one its material names)"
    )
    p.add_argument(
        "--via-basis",
        action="store_true",
        help="with a closest map (--map closest, or its saved map): transfer through the OFP "
        "bases (the paper's transfer: smoother where the map is noisy) instead of the exact "
        "pull-back; then --k1/--k2/--order/--preset/--tol apply",
    )
    p.add_argument(
        "--pull-back",
        action="store_true",
        help="with an estimated or given map: each target vertex takes its source vertex's "
        "value, with no OFP basis (sharper colors where the map is right, noisier where it is "
        "not); a closest map does this by default, at the exact surface point",
    )
    p.add_argument(
        "--uv-atlas",
        action="store_true",
        help="a textured or vertex-colored source onto a mesh target WITHOUT UVs: give the "
        "target a new UV atlas (Open3D's compute_uvatlas) and bake the colors into it (output "
        ".obj/.glb/.gltf)",
    )
    p.add_argument(
        "--texture-size",
        type=bounded_int(1, MAX_TEXTURE_SIZE),
        default=None,
        help=f"size of the baked texture image in pixels ({TEXTURE_SIZE}; at most "
        f"{MAX_TEXTURE_SIZE}); "
        "for a bake only (a source mesh onto a target with UVs, or --uv-atlas)",
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        help="colored target (mesh/cloud), or .npy values; with several targets a folder",
    )
    add_collection_options(p)
    p.set_defaults(func=run)


def _inputs(args: argparse.Namespace) -> tuple[str | None, ...]:
    """Return the files this command reads (flag values that are not files are skipped)."""
    return (args.source, args.target, args.signal, args.texture, *args.map.split(","),
            args.landmarks, args.basis_1, args.basis_2)  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """Read, match (or read the map), transfer, write (for each target)."""
    from ..boundary.bake import has_uvs
    from ..workflows.pipeline import transfer_function

    if is_collection(args.target):
        return _run_many(args)
    check_single(args)
    args.target = args.target[0]
    if args.uv_atlas and (
        args.signal is not None or not args.output.lower().endswith((".obj", ".glb", ".gltf"))
    ):
        raise UsageError(
            "--uv-atlas bakes the source's colors into a new atlas: it needs an "
            ".obj/.glb/.gltf output (-o) and no --signal"
        )
    inputs = _inputs(args)
    check_output(
        args.output, (*MESH_OUT, *CLOUD_OUT, ".npy"), inputs=inputs, side=signal_sides(args)
    )
    pair = read_pair(args)
    check_output_kind(args.output, pair.F2)
    closest = _closest(args, pair)
    if args.via_basis and args.pull_back:
        raise UsageError(
            "--via-basis transfers through the OFP bases and --pull-back without them: give "
            "one of them"
        )
    if args.via_basis and not closest:
        raise UsageError(
            "--via-basis applies to a closest map (--map closest or its saved map): other maps "
            "go through the OFP bases already"
        )
    if args.via_basis and args.uv_atlas:
        raise UsageError(
            "--via-basis sends the colors to the target's vertices and --uv-atlas bakes them "
            "into a new atlas: give one of them"
        )
    if args.signal is None and _bakeable(pair, args.output, atlas=args.uv_atlas):
        if args.uv_atlas and has_uvs(pair.target):
            logger.warning(
                "%s has its own UVs: the texture is baked into them (--uv-atlas makes an atlas "
                "for a target without UVs only)",
                args.target,
            )
        return _bake(args, pair)
    if args.texture_size is not None:
        raise UsageError(
            "--texture-size applies to a bake (a textured or vertex-colored source mesh onto a "
            "mesh target with UVs, or --uv-atlas, written as .obj/.glb/.gltf); here the colors "
            "go to the vertices"
        )
    if args.uv_atlas:
        raise UsageError(
            "--uv-atlas needs a source mesh with a texture or vertex colors, a mesh target and "
            "an .obj/.glb/.gltf output"
        )
    if closest and not args.via_basis and not args.pull_back:
        _refuse_basis_flags(
            args,
            "the closest map's values are pulled back exactly, with no OFP basis; drop it, or "
            "add --via-basis to transfer through the bases",
            files=True,
        )
    elif args.pull_back:
        _refuse_basis_flags(
            args,
            "--pull-back carries the values through the map with no OFP basis; drop it, or "
            + ("replace --pull-back by --via-basis" if closest else "drop --pull-back")
            + " to transfer through the bases",
            files=True,
        )
    spec = args.signal or _default_signal(pair.source)
    if spec in ("colors", "texture"):  # refused before the warnings below (which contradicted)
        check_colors_output(args.output)
    textured_target = pair.F1 is not None and pair.F2 is not None and has_uvs(pair.target)
    if textured_target and args.signal in ("colors", "texture"):
        own = "the source's texture" if has_uvs(pair.source) else "them"
        logger.warning(
            "%s has UVs: --signal %s puts the source's colors on its vertices (blurrier) and "
            "the file written has no texture; leave out --signal to bake %s into its UV "
            "layout (output .obj/.glb/.gltf)",
            args.target,
            args.signal,
            own,
        )
    elif pair.F1 is None and pair.F2 is not None and has_uvs(pair.target):
        logger.warning(
            "%s is a point cloud: its colors go to the vertices of %s (a cloud has no surface "
            "to bake from) and the file written has no texture",
            args.source,
            args.target,
        )
    elif textured_target and args.signal is None and spec in ("colors", "texture"):
        what = "texture goes" if spec == "texture" else "vertex colors go"
        logger.warning(
            "%s has UVs, but %s cannot hold a texture: the source's %s to the "
            "target's vertex colors (blurrier) and the target's UVs are not written; write "
            ".obj/.glb/.gltf to bake them into the target's UVs",
            args.target,
            args.output,
            what,
        )
    f, kind = read_signal(pair.source, pair.V1, args.source, spec, args.texture, output=args.output)
    # positions sent to the target are written in its own units, as a detail is
    own_units = 1.0 if kind != "xyz" or pair.target_scale is None else 1.0 / pair.target_scale
    if args.pull_back or (closest and not args.via_basis):  # exact pull-back, no basis
        from ..workflows.pipeline import pull_back

        given = _map_without_bases(args, pair)
        surface = given.barycentric_21 is not None
        with stage("pull-back through the surface map" if surface else "pull-back"):
            if spec == "texture" and surface:
                # the texture itself at each target vertex's point on the source surface, not
                # the source's per-vertex samples interpolated there (a trial: error 0.022)
                from ..boundary.texture import mesh_texture

                texture = mesh_texture(pair.source, args.texture)  # read by read_signal above
                g = texture.sample(given.faces_21, given.barycentric_21)
            else:
                g = pull_back(f, given, pair.F1)
        written = write_result(args.output, pair.own_target, own_units * g, kind, protect=inputs)
        report([f"{args.source} -> {args.target}: {'exact ' * closest}pull-back, map "
                f"{_map_name(args, given)}", "wrote " + ", ".join(written)])  # fmt: skip
        return 0
    pair = map_first(args, pair)
    B1, B2, eig_1, eig_2 = bases_for_pair(args, pair)
    corr = estimate_or_use_map(args, pair, eig_1, eig_2)
    if corr.n_source != pair.V1.shape[0]:
        raise UsageError("the map does not belong to these shapes")
    with stage("transfer"):
        # an estimated map was judged by its quality, a map file by _check_given_map: the
        # transfer's own word on a collapsing map would say it again
        with _said_already("the given map is doubtful"):
            g = transfer_function(f, eig_1, eig_2, p2p_21=corr.p2p_21, bases=(B1, B2))
    written = write_result(args.output, pair.own_target, own_units * g, kind, protect=inputs)
    report(
        [
            f"{args.source} -> {args.target}: {B1.size} -> {B2.size} basis functions, map "
            f"{_map_name(args, corr)}",
            "wrote " + ", ".join(written),
        ]
    )
    return 0


@contextlib.contextmanager
def _said_already(prefix: str) -> Iterator[None]:
    """Drop the package's log records that start with ``prefix`` (said by the CLI before)."""

    def keep(record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(prefix)

    root = logging.getLogger("o3d_ofp")
    handlers = list(root.handlers)
    for handler in handlers:
        handler.addFilter(keep)
    try:
        yield
    finally:
        for handler in handlers:
            handler.removeFilter(keep)


def _run_many(args: argparse.Namespace) -> int:
    """One source onto many targets: colors, or the texture baked into each target's UVs.

    A source colored per vertex is baked when ``--texture-size`` or ``--uv-atlas`` asks for it;
    otherwise its colors go to the targets' vertices, in the targets' own formats (a target's
    texture image is then not written, with a warning in its record).
    """
    from ..boundary.io import read_geometry
    from ..boundary.texture import has_uvs, mesh_texture, no_texture_message, surface_colors

    refuse_flags(args, PAIR_ONLY)
    if args.texture is not None and not os.path.isfile(args.texture):
        raise UsageError(f"--texture {args.texture}: no such image file")
    if args.signal not in (None, "colors", "texture"):
        raise UsageError(
            f"--signal {args.signal}: with several targets the signal is colors or texture"
        )
    kind, signal = "colors", args.signal or "auto"
    why = "the source has no texture coordinates"
    if args.signal is not None:
        why = f"--signal {args.signal} sends the colors to the targets' vertices"
    else:
        source = read_geometry(args.source)
        try:  # a textured source: baked into the targets' own UV layouts, as for one target
            mesh_texture(source, args.texture)
            kind = "texture"
        except (TypeError, ValueError, FileNotFoundError) as exc:
            why = no_texture_message(args.source, exc)
            asked = args.texture_size is not None or args.uv_atlas
            if asked and not has_uvs(source) and args.texture is None:
                try:  # vertex colors, baked when asked (else the targets keep their formats)
                    surface_colors(source)
                    kind = "texture"
                except (TypeError, ValueError) as colors_exc:
                    why = f"{args.source}: {colors_exc}"
    if kind != "texture" and args.texture_size is not None:
        raise UsageError(
            f"--texture-size applies to a bake, and nothing is baked here: {why}"
        )
    return run_transfers(
        args,
        kind=kind,
        options={"k1": args.k1, "k2": args.k2, "signal": signal,
                 "texture_size": args.texture_size or TEXTURE_SIZE, "atlas": args.uv_atlas,
                 "texture": args.texture},
    )  # fmt: skip


def _bakeable(pair, output: str, *, atlas: bool = False) -> bool:
    """Tell whether to bake into the target's UVs.

    Yes for a source mesh with a texture or (without UVs) vertex colors, a target with UVs (or
    an atlas), and an OBJ/glTF output.
    """
    from ..boundary.bake import has_uvs
    from ..boundary.convert import vertex_colors

    return bool(
        pair.F1 is not None
        and pair.F2 is not None
        and (has_uvs(pair.source) or vertex_colors(pair.source) is not None)
        and (atlas or has_uvs(pair.target))
        and output.lower().endswith((".obj", ".glb", ".gltf"))
    )


def _map_name(args: argparse.Namespace, corr: Any) -> str:
    """How the map was made, and from which file when it was read (``ab.npz (estimate)``)."""
    if args.map in ("estimate", "closest", "identity") or corr.method == args.map:
        return str(corr.method)
    return f"{args.map} ({corr.method})"


def _default_signal(source: Any) -> str:
    """``colors``, or ``texture`` for a textured source without vertex colors.

    The texture is then carried as vertex colors (a target without UVs, or an output that
    cannot hold a texture), as the README promises.
    """
    from ..boundary.bake import has_uvs
    from ..boundary.convert import vertex_colors
    from ..boundary.texture import has_texture_image

    if vertex_colors(source) is None and has_uvs(source):
        if has_texture_image(source):  # (else the image is asked for next: --texture FILE)
            logger.info("the source has a texture and no vertex colors: its texture is "
                        "transferred")  # fmt: skip
        return "texture"
    return "colors"


#: The flags of the OFP bases (argparse dest, flag): unused by a bake or an exact pull-back.
_BASIS_FLAGS = (("k1", "--k1"), ("k2", "--k2"), ("order", "--order"), ("preset", "--preset"),
                ("tol", "--tol"))  # fmt: skip


def _closest(args: argparse.Namespace, pair: Any) -> bool:
    """Tell whether the map is a closest-point map (``--map closest`` or its saved map)."""
    corr = pair.correspondence
    return args.map == "closest" or (corr is not None and corr.method == "closest")


def _refuse_basis_flags(args: argparse.Namespace, why: str, *, files: bool = False) -> None:
    """Refuse the OFP basis flags given for a transfer that builds no OFP basis (``why``).

    With ``files``, also the basis files (``--basis-1``/``--basis-2``): no eigenbasis is used.
    """
    given = getattr(args, "given", set()) or set()
    named = [
        flag
        for dest, flag in _BASIS_FLAGS
        if (getattr(args, dest) is not None if dest in ("k1", "k2") else dest in given)
    ]
    if files:
        named += [flag for dest, flag in (("basis_1", "--basis-1"), ("basis_2", "--basis-2"))
                  if getattr(args, dest)]  # fmt: skip
    if named:
        raise UsageError(f"{'/'.join(named)} does not apply here: {why}")


def _map_without_bases(args: argparse.Namespace, pair: Any) -> Any:
    """Return the pair's map for a transfer without OFP bases (a bake, a pull-back).

    A closest, given or dense-path map as :func:`map_first` makes it; otherwise estimated
    from the two eigenbases alone. Saved with ``--save-map``.
    """
    from ..workflows.matching import ESTIMATION_K, required_k
    from ._common import eigenbases_of

    pair = map_first(args, pair)
    eigs = (None, None)
    if pair.correspondence is None:
        with stage("eigenbases for map estimation"):
            eigs = tuple(
                eigenbases_of(
                    args,
                    [
                        (path, V, F, required_k(V.shape[0], ESTIMATION_K))
                        for path, V, F in (
                            (args.source, pair.V1, pair.F1),
                            (args.target, pair.V2, pair.F2),
                        )
                    ],
                    clamp_k=True,
                )
            )
    return estimate_or_use_map(args, pair, *eigs)


def _check_texture(args: argparse.Namespace, source: Any) -> None:
    """Refuse, before any work, a bake whose colors cannot be read (named: file or flag)."""
    from ..boundary.texture import surface_colors

    try:
        surface_colors(source, args.texture)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        raise texture_error(args.source, args.texture, exc) from exc


def _bake(args: argparse.Namespace, pair) -> int:
    """Bake the source's texture (or vertex colors) into the target's UV layout and write it."""
    from ..boundary.bake import has_uvs, transfer_texture
    from ..boundary.io import write_geometry

    if args.via_basis:
        raise UsageError(
            "--via-basis sends colors through the OFP bases to the target's vertices; a bake "
            "reads the source through the map: add --signal colors, or drop --via-basis"
        )
    if args.pull_back:
        raise UsageError(
            "--pull-back puts values on the target's vertices; this run bakes the source's "
            "colors into the target's UVs, which reads them through the map with no OFP basis "
            "already: drop --pull-back, or add --signal colors for per-vertex colors"
        )
    instead = (
        ""
        if args.uv_atlas
        else f", or add --signal colors{' --via-basis' if _closest(args, pair) else ''} to "
        "transfer the colors to the target's vertices through the bases"
    )
    _refuse_basis_flags(
        args,
        f"a bake reads the source's colors through the map, with no OFP basis; drop it{instead}",
    )
    _check_texture(args, pair.source)
    size = args.texture_size or TEXTURE_SIZE
    corr = _map_without_bases(args, pair)
    with stage(f"texture bake ({size} x {size})"):
        try:
            out = transfer_texture(
                pair.source,
                pair.target,
                correspondence=corr,
                size=size,
                texture=args.texture,
                atlas=args.uv_atlas,
            )
        except (FileNotFoundError, TypeError) as exc:
            raise UsageError(str(exc)) from exc
    write_geometry(args.output, pair.in_target_units(out), protect=_inputs(args))
    report(
        [
            f"{args.source} -> {args.target}: "
            f"{'texture' if has_uvs(pair.source) else 'vertex colors'} baked in the target's "
            f"{'new UV atlas' if args.uv_atlas and not has_uvs(pair.target) else 'UV layout'} "
            f"({size} px), map {_map_name(args, corr)}",
            f"wrote {args.output} (with its material and texture image)",
        ]
    )
    return 0
