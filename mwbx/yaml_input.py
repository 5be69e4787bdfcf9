"""User YAML (configs, query files) read with bounds, and short echoes of bad values.

YAML aliases let a few hundred bytes name a tree of billions of nodes (an
"alias bomb": ``a: &a [1, 1]``, ``b: &b [*a, *a]``, …). PyYAML builds it as a
small shared graph, but everything that walks it as a tree afterwards
(validation, an error message echoing the value) takes time and memory
exponential in the file's size. :func:`load` counts the nodes of the
document's tree as aliases would expand it, on the small graph, and refuses a
document past :data:`MAX_NODES` (or nested past :data:`MAX_DEPTH`) before
anything walks it. :func:`short_repr` bounds what an error message echoes.
"""

from __future__ import annotations

import yaml

from mwbx.errors import MwbxError

# Nodes of a document with its aliases expanded: far above any real config
# or query file (a query file of 1000 queries is ~20 000 nodes), and few
# enough that validating them takes well under a second.
MAX_NODES = 200_000
# Nesting of collections; the deepest real file nests about 5 levels.
MAX_DEPTH = 100
# Characters of a value an error message echoes.
ECHO_CHARS = 200


def short_repr(value, limit: int = ECHO_CHARS) -> str:
  """``repr(value)`` cut to about ``limit`` characters (an alias-expanded or
  huge value is never formatted whole: containers are shown by their first
  items only)."""
  text = _bounded_repr(value, limit + 1)
  return text if len(text) <= limit else text[:limit] + f"… ({type(value).__name__})"


def _bounded_repr(value, limit: int) -> str:
  """A repr of at most about ``limit`` characters, built without formatting
  more of ``value`` than that (a shared alias graph repr'd whole is huge)."""
  if isinstance(value, (list, tuple, dict)):
    opening, closing = "{}" if isinstance(value, dict) else "()" if isinstance(value, tuple) else "[]"
    items = value.items() if isinstance(value, dict) else value
    out = opening
    for i, item in enumerate(items):
      if len(out) > limit:
        return out + ", …" + closing
      if i:
        out += ", "
      if isinstance(value, dict):
        k, v = item
        out += _bounded_repr(k, limit - len(out)) + ": " + _bounded_repr(v, limit - len(out))
      else:
        out += _bounded_repr(item, limit - len(out))
    return out + closing
  text = repr(value)
  return text if len(text) <= limit else text[:max(limit, 0)] + "…"


def load(text: str, source: str, malformed: str = "malformed YAML"):
  """Parses one YAML document with the safe loader, refusing alias bombs.

  Args:
    text: the document.
    source: the file name, for messages.
    malformed: how a message calls a document PyYAML cannot parse.

  Returns:
    the parsed value (None for an empty document).

  Raises:
    MwbxError: malformed YAML (one line: where, and PyYAML's problem),
      or a document whose tree, aliases expanded, has more than
      :data:`MAX_NODES` nodes or nests deeper than :data:`MAX_DEPTH`.
  """
  loader = yaml.SafeLoader(text)
  try:
    node = loader.get_single_node()
    if node is None:
      return None
    _check_size(node, source)
    try:
      return loader.construct_document(node)
    except (ValueError, OverflowError, KeyError, TypeError) as err:  # an int of 5000 digits, `!!bool maybe`
      raise MwbxError(f"{source}: a value YAML cannot convert ({_why_not_converted(err)})") from None
  except yaml.YAMLError as err:
    raise MwbxError(f"{source}: {malformed}: {short_repr_text(yaml_error_line(err), 300)}") from None
  except RecursionError:  # PyYAML's composer recurses once per nesting level
    raise MwbxError(f"{source}: YAML nested too deeply (more than {MAX_DEPTH} levels)") from None
  finally:
    loader.dispose()


def _why_not_converted(err: Exception) -> str:
  """Why a scalar did not convert, without the scalar: Python's messages
  quote the value after a colon (``invalid literal for int() with base 10:
  'hunter2'``), and a file's content is never echoed.

  >>> _why_not_converted(ValueError("could not convert string to float: 'x'"))
  'could not convert string to float'
  """
  if isinstance(err, (ValueError, OverflowError)):
    return short_repr_text(str(err).split(": ", 1)[0], 120)
  return "a tagged value that is not of its tag's type"


def yaml_error_line(err: yaml.YAMLError) -> str:
  """PyYAML's error on one line: where (line and column, 1-based) and what
  went wrong, without the snippet and caret it draws under it.

  >>> yaml_error_line(yaml.YAMLError("bad"))
  'bad'
  """
  if not isinstance(err, yaml.MarkedYAMLError):
    return " ".join(str(err).split())
  mark = err.problem_mark or err.context_mark
  where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
  what = "; ".join(p for p in (err.context, err.problem) if p)
  return where + " ".join(what.split())


def short_repr_text(text: str, limit: int) -> str:
  """``text`` cut to ``limit`` characters."""
  return text if len(text) <= limit else text[:limit] + "…"


def _check_size(root, source: str) -> None:
  """Counts the expanded tree of ``root`` once per distinct node (memoized),
  iteratively; a node reached from itself (``&a [*a]``) is an infinite tree."""
  size: dict[int, int] = {}
  depth: dict[int, int] = {}
  on_path: set[int] = set()
  stack = [(root, False)]
  while stack:
    node, children_done = stack.pop()
    key = id(node)
    children = _children(node)
    if children_done:
      on_path.discard(key)
      size[key] = 1 + sum(size[id(c)] for c in children)
      depth[key] = 1 + max((depth[id(c)] for c in children), default=0)
      if size[key] > MAX_NODES:
        raise MwbxError(f"{source}: YAML expands to more than {MAX_NODES:,} values (aliases repeating"
                        f" aliases?); refused")
      if depth[key] > MAX_DEPTH:
        raise MwbxError(f"{source}: YAML nested too deeply (more than {MAX_DEPTH} levels)")
      continue
    if key in size:
      continue
    if key in on_path:
      raise MwbxError(f"{source}: YAML alias refers to a collection that contains it (an infinite value);"
                      f" refused")
    on_path.add(key)
    stack.append((node, True))
    for child in children:
      if id(child) in on_path:
        raise MwbxError(f"{source}: YAML alias refers to a collection that contains it (an infinite"
                        f" value); refused")
      if id(child) not in size:
        stack.append((child, False))


def _children(node) -> list:
  if isinstance(node, yaml.SequenceNode):
    return list(node.value)
  if isinstance(node, yaml.MappingNode):
    return [part for pair in node.value for part in pair]
  return []
