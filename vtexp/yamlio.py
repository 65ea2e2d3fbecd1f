"""Safe YAML loading that remembers where every key came from.

Only YAML's plain data types are accepted (``yaml.SafeLoader``): a Python
object tag is an error, never code. Alongside the data, :func:`load_yaml`
returns a map from each key path (a tuple of keys and list indices) to its
1-based line, so that schema errors can name the line.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import InputError

KeyPath = tuple[Any, ...]


@dataclass
class LoadedYaml:
    data: Any
    path: str
    text: str
    lines: dict[KeyPath, int] = field(default_factory=dict)

    def line_of(self, keypath: KeyPath) -> int | None:
        """Line of ``keypath`` or of its nearest ancestor that has one."""
        kp = tuple(keypath)
        while kp:
            if kp in self.lines:
                return self.lines[kp]
            kp = kp[:-1]
        return self.lines.get((), None)


#: A key's text read as YAML reads a key (on libyaml where PyYAML has it: the same values).
_KEY_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _record_lines(node: yaml.Node, prefix: KeyPath, out: dict[KeyPath, int]) -> None:
    out.setdefault(prefix, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for knode, vnode in node.value:
            key = knode.value if isinstance(knode, yaml.ScalarNode) else str(knode.value)
            # Mapping keys that look like integers are constructed as ints.
            try:
                key_obj: Any = yaml.load(key, Loader=_KEY_LOADER) \
                    if isinstance(knode, yaml.ScalarNode) else key
                if not isinstance(key_obj, (str, int, float, bool)):
                    key_obj = key
            except yaml.YAMLError:
                key_obj = key
            kp = prefix + (key_obj,)
            out[kp] = knode.start_mark.line + 1
            _record_lines(vnode, kp, out)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            kp = prefix + (i,)
            out[kp] = item.start_mark.line + 1
            _record_lines(item, kp, out)


class _UniqueKeys:
    """Refuses duplicate keys (YAML silently keeps the last)."""

    def construct_mapping(self, node, deep=False):
        seen: dict[Any, int] = {}
        for knode, _ in node.value:
            key = self.construct_object(knode, deep=deep)
            try:
                hash(key)
            except TypeError:
                continue
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None,
                    f"duplicate key {key!r} (first on line {seen[key]})",
                    knode.start_mark)
            seen[key] = knode.start_mark.line + 1
        return super().construct_mapping(node, deep=deep)


class _UniqueKeyLoader(_UniqueKeys, yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys: PyYAML's own reader, whose messages name
    what it refuses and where."""


#: The same loader on libyaml (PyYAML's C parser), where PyYAML was built with it: an
#: experiment file is read about ten times faster. A document it refuses is read again by
#: the Python loader, so a mistake is reported in the same words either way.
_FastLoader = (type("_FastLoader", (_UniqueKeys, yaml.CSafeLoader), {})
               if getattr(yaml, "__with_libyaml__", False) else None)


#: Limits checked before a document is built: an experiment file is a few kilobytes and a
#: few levels deep; past these it is a mistake or an attack (a link to /dev/zero, aliases
#: that repeat aliases), refused before it takes the memory or the time.
MAX_BYTES = 1_000_000
MAX_DEPTH = 64
MAX_VALUES = 100_000


def _check_extent(node: yaml.Node, path: str) -> None:
    """Refuse a document nested deeper than MAX_DEPTH or of more than MAX_VALUES values
    with its aliases expanded (walked without recursion, stopping at the limit)."""
    stack, count = [(node, 1)], 0
    while stack:
        nd, depth = stack.pop()
        count += 1
        if depth > MAX_DEPTH:
            raise InputError(f"nested more than {MAX_DEPTH} levels deep; an experiment is a "
                             "few levels deep", path=path, line=nd.start_mark.line + 1)
        if count > MAX_VALUES:
            raise InputError(f"holds more than {MAX_VALUES:,} values once its aliases (*name) "
                             "are expanded; an experiment holds far fewer", path=path)
        if isinstance(nd, yaml.MappingNode):
            stack.extend((x, depth + 1) for pair in nd.value for x in pair)
        elif isinstance(nd, yaml.SequenceNode):
            stack.extend((x, depth + 1) for x in nd.value)


#: Documents already read by this process, by path and text: a command reads its experiment
#: several times (checked, compiled, recorded), and a test run reads the same few files
#: hundreds of times. Each caller gets its own copy of the data. Only texts of an
#: experiment's size are kept (at most _READ_MAX of them, of up to _READ_BYTES each).
_READ: dict[tuple[str, str], tuple[Any, dict[KeyPath, int]]] = {}
_READ_MAX = 64
_READ_BYTES = 65_536


def load_yaml_text(text: str, path: str = "<string>") -> LoadedYaml:
    done = _READ.get((path, text))
    if done is None:
        done = _read(text, path)
        if len(text) <= _READ_BYTES:
            if len(_READ) >= _READ_MAX:
                _READ.pop(next(iter(_READ)))
            _READ[(path, text)] = done
    data, lines = done
    return LoadedYaml(data=copy.deepcopy(data), path=path, text=text, lines=dict(lines))


def _read(text: str, path: str) -> tuple[Any, dict[KeyPath, int]]:
    if len(text) > MAX_BYTES:
        raise InputError(f"is over {MAX_BYTES:,} characters long; an experiment file is a few "
                         "kilobytes", path=path)
    if _FastLoader is not None:
        try:
            node, data = _compose(_FastLoader, text, path)
        except (yaml.YAMLError, RecursionError):
            pass                            # refused: the Python loader says why, below
        else:
            return data, _lines(node)
    try:
        node, data = _compose(_UniqueKeyLoader, text, path)
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1 if isinstance(exc.position, int) else None
        ch = exc.character
        code = ord(ch) if isinstance(ch, str) and len(ch) == 1 else ch
        what = f"U+{code:04X}" if isinstance(code, int) else repr(ch)
        raise InputError(f"a character YAML does not allow ({what}, {exc.reason}); remove it",
                         path=path, line=line) from None
    except RecursionError:
        raise InputError("nested too deeply to read; an experiment is a few levels deep",
                         path=path) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        problem = exc.problem or str(exc)
        if "could not determine a constructor" in problem:
            problem = (f"{problem.strip()}: tags that create objects are not allowed; "
                       "use plain YAML values")
        context = f" ({exc.context})" if exc.context and exc.context not in problem else ""
        raise InputError(f"YAML syntax error: {problem}{context}", path=path, line=line) from None
    except yaml.YAMLError as exc:
        raise InputError(f"YAML error: {exc}", path=path) from None
    return data, _lines(node)


def _compose(loader_class, text: str, path: str) -> tuple[yaml.Node, Any]:
    """The document's node tree (its extent checked before anything is built) and data."""
    loader = None
    try:
        loader = loader_class(text)         # reading starts here: a character YAML refuses
        node = loader.get_single_node()
        if node is None:
            raise InputError("the file is empty; expected a YAML mapping", path=path, line=1)
        _check_extent(node, path)
        return node, loader.construct_document(node)
    finally:
        if loader is not None:
            loader.dispose()


def _lines(node: yaml.Node) -> dict[KeyPath, int]:
    lines: dict[KeyPath, int] = {}
    _record_lines(node, (), lines)
    return lines


def load_yaml(path: str | Path) -> LoadedYaml:
    p = Path(path)
    try:
        with open(p, "rb") as f:            # at most the limit: a link to /dev/zero ends
            raw = f.read(MAX_BYTES + 1)
        if len(raw) > MAX_BYTES:
            raise InputError(f"is over {MAX_BYTES:,} bytes long; an experiment file is a few "
                             "kilobytes", path=str(p))
        # line ends as text mode reads them (\r\n and \r become \n)
        text = raw.decode("utf-8").replace("\r\n", "\n").replace("\r", "\n")
    except FileNotFoundError:
        raise InputError("file not found", path=str(p)) from None
    except IsADirectoryError:
        raise InputError("is a directory, expected a YAML file", path=str(p)) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text ({exc.reason} at byte {exc.start})", path=str(p)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", path=str(p)) from None
    return load_yaml_text(text, str(p))


def format_validation_error(exc, loaded: LoadedYaml, root: KeyPath = ()) -> InputError:
    """Turn the first error of a pydantic ``ValidationError`` into an InputError."""
    errors = exc.errors(include_url=False)
    err = errors[0]
    loc = tuple(x for x in err["loc"] if not _is_union_tag(x))
    # A question's kind appears in the location as a tag: question.rating.low -> question.low
    if len(loc) > 1 and loc[0] == "question" and loc[1] in ("choice", "rating", "number"):
        loc = loc[:1] + loc[2:]
    elif len(loc) > 2 and loc[0] == "questions" and loc[2] in ("choice", "rating", "number"):
        loc = loc[:2] + loc[3:]
    full = root + loc
    key = ".".join(str(x) for x in full) or None
    msg = _message(err)
    more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" \
        if len(errors) > 1 else ""
    return InputError(msg + more, path=loaded.path, line=loaded.line_of(full), key=key)


def _is_union_tag(x: Any) -> bool:
    # pydantic puts the chosen union member or function name into ``loc``.
    return isinstance(x, str) and (x.startswith("function-") or "[" in x)


def _message(err: dict) -> str:
    typ = err["type"]
    inp = err.get("input")
    if typ == "extra_forbidden":
        return "unknown key; check its spelling against docs/experiment-format.md"
    if typ == "missing":
        return "required key is missing"
    msg = err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    if isinstance(inp, (str, int, float, bool)) and typ not in ("value_error",):
        msg += f" (got {inp!r})"
    return msg
