"""Reading a scene: TOML file + --set overrides -> validated Scene."""

import tomllib
from pathlib import Path

from psph.errors import SceneError, UsageError
from psph.scene.schema import Scene
from psph.scene.validate import build

MAX_SCENE_BYTES = 1 << 20


def parse_override(text: str):
    """'key.path=value' -> (['key', 'path'], value); the value is a TOML literal, a bare word a string."""
    if "=" not in text:
        raise UsageError(f"--set {text!r}: expected key.path=value")
    key, raw = text.split("=", 1)
    key = key.strip()
    parts = key.split(".")
    if not key or any(not p or not p.replace("_", "").isalnum() for p in parts):
        raise UsageError(f"--set {text!r}: invalid key path {key!r}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError):
        value = raw.strip()
    return parts, value


def apply_overrides(table: dict, overrides) -> dict:
    """Set each key path in a copy of `table` (creating tables on the way). A number indexes an array of
    tables: `bodies.1.motion.law=ramp` sets the second [[bodies]] entry's law."""
    import copy

    table = copy.deepcopy(table)
    for text in overrides:
        parts, value = parse_override(text)
        node = table
        for k, part in enumerate(parts[:-1]):
            where = ".".join(parts[: k + 1])
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    raise SceneError(".".join(parts[:k]), f"has {len(node)} entries: {part!r} is not an index "
                                     f"0-{len(node) - 1}")
                nxt = node[int(part)]
            else:
                nxt = node.setdefault(part, {})
            tables = isinstance(nxt, dict) or (isinstance(nxt, list) and all(isinstance(e, dict) for e in nxt))
            if not tables:
                raise SceneError(where, "is a value, not a table: cannot --set below it")
            node = nxt
        if isinstance(node, list):
            raise SceneError(".".join(parts[:-1]), f"is an array of tables: --set one entry's key "
                             f"({'.'.join(parts[:-1])}.N.key)")
        node[parts[-1]] = value
    return table


def _is_hdf5(path) -> bool:
    """Whether the file starts with HDF5's signature (a checkpoint or a snapshot)."""
    with open(path, "rb") as f:
        return f.read(8) == b"\x89HDF\r\n\x1a\n"


def read_table(path) -> dict:
    """Parse a TOML scene file (data only; nothing in it is executed)."""
    path = Path(path)
    if not path.is_file():
        what = ("is a directory" if path.is_dir() else "is not a regular file" if path.exists() else "not found")
        raise UsageError(f"scene file {str(path)!r} {what}")
    if path.stat().st_size > MAX_SCENE_BYTES:
        raise SceneError("", f"scene file {str(path)!r} is larger than {MAX_SCENE_BYTES} bytes")
    try:
        text = path.read_bytes().decode("utf-8-sig")  # (a byte-order mark, as some editors save)
    except UnicodeDecodeError as exc:
        hint = "; to continue a run from a checkpoint: psph run --restart FILE" if _is_hdf5(path) else ""
        raise SceneError("", f"scene file {str(path)!r} is not UTF-8 text ({exc.reason}){hint}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError("", f"scene file {str(path)!r} is not valid TOML: {exc}") from None
    except RecursionError:
        raise SceneError("", f"scene file {str(path)!r} is nested too deeply") from None


def load_scene(path, overrides=()) -> Scene:
    """Read, override and validate a scene; raises SceneError naming the offending key."""
    table = apply_overrides(read_table(path), overrides)
    return scene_from_table(table)


def scene_from_table(table: dict) -> Scene:
    try:
        return build(Scene, table)
    except RecursionError:
        raise SceneError("", "scene is nested too deeply") from None
