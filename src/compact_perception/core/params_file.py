"""Reading a params file: :func:`load_params` refuses a file that is missing, too large, not
UTF-8, not YAML or that writes a key twice in one mapping, then validates it (:func:`parse_params`)."""
from __future__ import annotations

from pathlib import Path

import yaml

from .params_errors import ParamsError, _one_line
from .params_schema import Params, parse_params

__all__ = ["load_params", "UniqueKeyLoader", "DuplicateKeyError", "MAX_PARAMS_BYTES"]


class DuplicateKeyError(yaml.YAMLError):
    """A mapping of a YAML file names one key twice."""


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that rejects a key written twice in one mapping: PyYAML would keep the
    last value silently, while DVC (ruamel) rejects the file, so ``dvc status`` and the stages
    would disagree. A merge key (``<<: *anchor``) is not a duplicate of the keys it supplies."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node)
            if key in seen:
                raise DuplicateKeyError(f"duplicate key {key!r} at line {key_node.start_mark.line + 1}")
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


#: A params file larger than this is not a params file (params.yaml is ~20 kB): refused at once,
#: before YAML reads it (a 50 MB file took minutes to reach its error).
MAX_PARAMS_BYTES = 1 << 20


def _params_text(path: Path) -> str:
    """The text of params file ``path``: :class:`ParamsError` for a file that is missing, too
    large (:data:`MAX_PARAMS_BYTES`), unreadable or not UTF-8, naming the file."""
    try:
        if not path.is_file():
            raise ParamsError(f"{path}: file not found")
        size = path.stat().st_size
        if size > MAX_PARAMS_BYTES:
            raise ParamsError(f"{path}: {size} bytes, too large for a params file (at most {MAX_PARAMS_BYTES})")
        raw = path.read_bytes()[:MAX_PARAMS_BYTES + 1]
    except OSError as err:
        raise ParamsError(f"{path}: could not read ({err.strerror or err})") from None
    if len(raw) > MAX_PARAMS_BYTES:  # grew since stat
        raise ParamsError(f"{path}: too large for a params file (at most {MAX_PARAMS_BYTES} bytes)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        line = raw[:err.start].count(b"\n") + 1
        raise ParamsError(f"{path}: not UTF-8 text (byte 0x{raw[err.start]:02x} at line {line})") from None


def load_params(path: str | Path = "params.yaml") -> Params:
    """Read and validate params.yaml (a key written twice in one mapping is an error; a file
    that is not UTF-8 or larger than :data:`MAX_PARAMS_BYTES` is refused before YAML reads it)."""
    path = Path(path)
    text = _params_text(path)
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)
    except DuplicateKeyError as err:
        raise ParamsError(f"{path}: {err}") from None
    except yaml.YAMLError as err:
        raise ParamsError(f"{path}: not valid YAML: {_one_line(err)}") from None
    except RecursionError:
        raise ParamsError(f"{path}: not valid YAML: nested too deeply") from None
    return parse_params(data, str(path))
