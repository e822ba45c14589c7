"""Generate or check the parameter YAML files in the packages' `config/` folders (no ROS).

A config file generated from a `NodeConfig` class names it in its second line
(`# Generated from MODULE:CLASS; ...`). `python -m robot_common.config_files` checks every such
file under the workspace's `src/` against its class (exit 1 and a list when one differs);
`--write` rewrites them from the classes.
"""
import argparse
import importlib
import re
import sys
from pathlib import Path
from typing import List, Tuple

__all__ = ["generated_files", "stale_files", "main"]

_HEADER = re.compile(r"^# Generated from ([\w.]+):(\w+);")


def generated_files(src_root: Path) -> List[Tuple[Path, str, type]]:
    """(path, title, config class) of every generated YAML file under `src_root`/*/config/."""
    found = []
    for path in sorted(src_root.glob("*/config/*.yaml")):
        lines = path.read_text().splitlines()
        match = _HEADER.match(lines[1]) if len(lines) > 1 else None
        if match:
            module, name = match.groups()
            found.append((path, lines[0][2:], getattr(importlib.import_module(module), name)))
    return found


def stale_files(src_root: Path, *, write: bool = False) -> List[Path]:
    """Generated files whose text differs from their class's rendering (rewritten if `write`)."""
    stale = []
    for path, title, config_cls in generated_files(src_root):
        text = config_cls.render_yaml(title)
        if path.read_text() != text:
            stale.append(path)
            if write:
                path.write_text(text)
    return stale


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--src", type=Path, default=Path(__file__).resolve().parents[3],
                        help="the workspace's src/ folder (default: the one holding this package)")
    parser.add_argument("--write", action="store_true", help="rewrite stale files")
    args = parser.parse_args(argv)
    stale = stale_files(args.src, write=args.write)
    for path in stale:
        print(f"{'rewrote' if args.write else 'stale'}: {path}")
    return 1 if stale and not args.write else 0


if __name__ == "__main__":
    sys.exit(main())
