"""Reading a params file: :func:`load_params` refuses a file that is missing, too large, not
UTF-8, not YAML, that writes a key twice in one mapping or whose aliases expand it beyond
:data:`MAX_PARAMS_VALUES` values, then validates it (:func:`parse_params`)."""
from __future__ import annotations

import logging
from pathlib import Path

import yaml

from .errors import ParamsError, _one_line
from .former import upgrade_params
from .schema import Params, parse_params

__all__ = ["load_params", "UniqueKeyLoader", "DuplicateKeyError", "ExpansionError", "MAX_PARAMS_BYTES",
           "MAX_PARAMS_VALUES"]

log = logging.getLogger(__name__)

#: The most values (mappings, lists and scalars; an alias counts as everything its anchor holds)
#: a params document may hold. params.yaml holds under a thousand; an alias-free file under
#: :data:`MAX_PARAMS_BYTES` can hold about 500,000 and is refused past the bound too. Nested
#: aliases ("billion laughs": ten aliases of ten aliases of ...) make a few lines stand for 10^9
#: values, which every later step (the recipe merge, the schema, an error's repr) would copy:
#: such a document is refused once composed, before anything is built from it.
MAX_PARAMS_VALUES = 100_000


class DuplicateKeyError(yaml.YAMLError):
    """A mapping of a YAML file names one key twice."""


class ExpansionError(yaml.YAMLError):
    """A YAML document whose aliases expand beyond :data:`MAX_PARAMS_VALUES` values, or refer to
    themselves; the message names the key that holds the expansion."""


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def expanded_sizes(root: yaml.Node, limit: int) -> dict[int, int]:
    """``id(node) -> `` the values each node of a composed document stands for once its aliases
    are expanded (itself and everything under it), capped at ``limit + 1``. PyYAML composes an
    alias as the anchored node itself, so each node is counted once (a shared node is not walked
    again): time and memory grow with the text, not with what it expands to. A node inside
    itself (``&a [*a]``) raises :class:`ExpansionError`."""
    size: dict[int, int] = {}
    open_: set[int] = set()                      # the nodes on the path to the current one
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        if finished:
            open_.discard(id(node))
            size[id(node)] = min(limit + 1, 1 + sum(size[id(c)] for c in _children(node)))
            continue
        if id(node) in size:
            continue
        open_.add(id(node))
        stack.append((node, True))
        for child in _children(node):
            if id(child) in open_:
                raise ExpansionError(f"an alias inside its own anchor at line {child.start_mark.line + 1}")
            if id(child) not in size:
                stack.append((child, False))
    return size


def _key_of(root: yaml.Node, size: dict[int, int], limit: int) -> str:
    """The dotted key of the deepest mapping entry on the way to the expansion past ``limit``."""
    path: list[str] = []
    node = root
    while isinstance(node, yaml.MappingNode):
        over = [(k, v) for k, v in node.value if size[id(v)] > limit or size[id(k)] > limit]
        if not over:
            break
        key, node = over[0]
        path.append(str(key.value)[:40] if isinstance(key, yaml.ScalarNode) else "<key>")
    return ".".join(path) or "<root>"


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

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        """An integer; one too long for Python to read (past 4300 digits) is a YAML error at its line."""
        try:
            return super().construct_yaml_int(node)
        except ValueError:
            raise yaml.constructor.ConstructorError(None, None, f"an integer of {len(node.value)} digits, too long "
                                                    "to read", node.start_mark) from None

    def get_single_node(self) -> yaml.Node | None:
        """The composed document, refused (:class:`ExpansionError`) when its aliases expand it past
        :data:`MAX_PARAMS_VALUES` values: checked before anything is constructed from it."""
        node = super().get_single_node()
        if node is not None:
            size = expanded_sizes(node, MAX_PARAMS_VALUES)
            if size[id(node)] > MAX_PARAMS_VALUES:
                raise ExpansionError(f"{_key_of(node, size, MAX_PARAMS_VALUES)}: more than {MAX_PARAMS_VALUES} "
                                     "values once the YAML aliases are expanded (params.yaml holds under a thousand; "
                                     "an alias repeats everything its anchor holds)")
        return node


UniqueKeyLoader.add_constructor("tag:yaml.org,2002:int", UniqueKeyLoader.construct_yaml_int)

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


def load_params(path: str | Path = "params.yaml", *, former: bool = False) -> Params:
    """Read and validate params.yaml (a key written twice in one mapping is an error; a file
    that is not UTF-8 or larger than :data:`MAX_PARAMS_BYTES` is refused before YAML reads it;
    one whose aliases expand past :data:`MAX_PARAMS_VALUES` values before anything is built).
    ``former``: a file of an earlier commit, whose layouts :mod:`.former` lists, is read in
    today's layout first (each change logged); the pipeline's stages never pass it."""
    path = Path(path)
    text = _params_text(path)
    try:
        data = yaml.load(text, Loader=UniqueKeyLoader)
    except (DuplicateKeyError, ExpansionError) as err:
        raise ParamsError(f"{path}: {err}") from None
    except yaml.YAMLError as err:
        raise ParamsError(f"{path}: not valid YAML: {_one_line(err)}") from None
    except RecursionError:
        raise ParamsError(f"{path}: not valid YAML: nested too deeply") from None
    if former:
        data, changes = upgrade_params(data)
        for change in changes:
            log.info("%s: former layout read as today's: %s", path, change)
    return parse_params(data, str(path))
