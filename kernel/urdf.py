"""What the calibration tool (feepe) and the templates of a user's end-effector (syneepose) both need of a
user's URDF: where its mesh names (package://pkg/path, file://) point on this machine, and the links below a
link (the end-effector's)."""

from __future__ import annotations

from pathlib import Path


def mesh_path(name: str, urdf: Path, mesh_dir: Path | None = None) -> Path:
    """package:// and file:// names, and names relative to the URDF, as files: looked up as given, under
    `mesh_dir` (default: the URDF's folder) with and without the package name. The first that exists, else
    the first candidate under `mesh_dir` (for the caller's error)."""
    urdf = Path(urdf)
    root = Path(mesh_dir) if mesh_dir else urdf.parent
    for prefix in ("package://", "file://"):
        if name.startswith(prefix):
            rest = name[len(prefix):]
            candidates = [Path(rest), root / rest, root / rest.split("/", 1)[-1]]
            return next((p for p in candidates if p.is_file()), candidates[1])
    if Path(name).is_absolute():
        return Path(name)
    beside = urdf.parent / name
    return beside if beside.is_file() else root / name


def links_below(link: str, joints) -> set[str]:
    """`link` and every link under it, over `joints` as (parent, child) link-name pairs."""
    below, frontier = {link}, [link]
    while frontier:
        parent = frontier.pop()
        for joint_parent, child in joints:
            if joint_parent == parent and child not in below:
                below.add(child)
                frontier.append(child)
    return below
