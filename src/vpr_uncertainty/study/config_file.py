"""Reading a grid configuration file (TOML or YAML) into its top-level mapping, with one-line syntax errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["read_mapping"]


def read_mapping(path: Path) -> dict[str, Any]:
    """The top-level mapping of a TOML or YAML file; a syntax error is one line naming the file and the line."""
    suffix = path.suffix.lower()
    if suffix == ".toml":
        import tomllib

        try:
            with path.open("rb") as file:
                return tomllib.load(file)
        except tomllib.TOMLDecodeError as error:  # its message ends with "(at line L, column C)"
            raise ValueError(f"{path}: invalid TOML: {error}") from None
        except UnicodeDecodeError as error:
            raise ValueError(f"{path}: not a UTF-8 text file ({error.reason} at byte {error.start})") from None
    if suffix in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError as error:
            raise ImportError(
                f"reading {path} needs pyyaml (pip install pyyaml), or write the config as TOML"
            ) from error
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            where = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
            problem = getattr(error, "problem", None) or str(error).splitlines()[0]
            raise ValueError(f"{path}{where}: invalid YAML: {problem}") from None
        except UnicodeDecodeError as error:
            raise ValueError(f"{path}: not a UTF-8 text file ({error.reason} at byte {error.start})") from None
        if not isinstance(data, dict):
            raise ValueError(f"{path}: the configuration must be a mapping at the top level")
        return data
    raise ValueError(f"unsupported configuration file {path}: expected .toml, .yaml or .yml")
