"""The persistent compilation cache every command uses, and JAX's own count of compile time.

A run's filter program takes 12-15 s to compile on a 2-core CPU; the program depends only on the
static settings and the log's segment shapes, so a second run loads it from disk instead.
:func:`enable_compile_cache` points JAX's persistent compilation cache at one directory:
``$NANOSLAM_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/nanoslam-jax/jax`` (``~/.cache/...``).

Two layers, both in that directory:

* **XLA executables**, JAX's persistent compilation cache. Its key is a hash of the compiled
  module (every static shape, constant and branch, so every static config setting and the
  segment shapes), the compile options and XLA flags, the device kind and count, and the
  versions of jax, jaxlib and XLA. Any change of this project's code that changes the program
  changes the module, hence the key; a change that does not change the module gives the same
  executable. The project's version is not added: it would add no safety and would only make
  every upgrade (and every editable install, whose version does not move with the commits)
  recompile from scratch.
* **Traced programs** (``exported/``), for the filter's chunk program only
  (:func:`compile_program`): JAX needs the traced and lowered module to compute the key above,
  and tracing the filter step takes 2-4 s, most of what a second run would still spend. The
  lowered program is kept with :mod:`jax.export` under a key of our own that covers everything
  the trace reads: the source of every module of this package, the name and version of every
  installed distribution (jax, jaxlib, equinox, optimistix, numpy, ...), JAX's configuration
  (float64, device count, ...), the static settings, and the shapes, dtypes and placement of
  the arguments. Any edit of the package, any upgrade and any other static setting therefore
  traces afresh; the XLA layer then still loads the executable when the module is unchanged.
  An entry is data only: JAX's serialised module and a JSON header with the output tree; reading
  it imports, unpickles and calls nothing, and an entry that does not load or match is a miss.

:class:`CompileStats` (:mod:`nanoslam_jax.lib._compile_stats`, re-exported here) counts JAX's
own compile time for ``metrics.json`` and the benchmark, and tells an installed watcher of each
compilation.
"""

from __future__ import annotations

import functools
import gc
import hashlib
import importlib.metadata
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Optional

import jax

from nanoslam_jax.lib._compile_stats import (
    CompileStats as CompileStats,
    CompileWatcher as CompileWatcher,
    ProgramInfo as ProgramInfo,
    compile_stats as compile_stats,
    watch_compiles as watch_compiles,
    watched_compile as watched_compile,
)

__all__ = [
    "CACHE_ENV",
    "CompileStats",
    "CompileWatcher",
    "ProgramInfo",
    "compile_program",
    "compile_stats",
    "default_cache_dir",
    "enable_compile_cache",
    "memory_maps",
    "program_cache",
    "program_key",
    "release_programs",
    "watch_compiles",
    "watched_compile",
]

#: Environment variable that moves the cache directory.
CACHE_ENV = "NANOSLAM_CACHE_DIR"

#: Programs that compile faster than this are not written to the cache (JAX's default is 1 s). The
#: filter's programs all take longer; the many small eager operations of loading and scoring a
#: run would only fill the directory with entries that cost more to read than to compile.
MIN_COMPILE_TIME_S = 0.5


def default_cache_dir() -> Path:
    """``$NANOSLAM_CACHE_DIR``, else ``$XDG_CACHE_HOME/nanoslam-jax/jax`` (``~/.cache`` by default)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "nanoslam-jax" / "jax"


def enable_compile_cache(path: str | os.PathLike | None = None) -> str:
    """Keep compiled programs in JAX's persistent compilation cache.

    Args:
        path: the cache directory (default: :func:`default_cache_dir`). When this process already
            uses a cache directory (set earlier, or by ``JAX_COMPILATION_CACHE_DIR``), that one is kept.

    Returns:
        The cache directory in use.

    Raises:
        ValueError: naming the directory and ``NANOSLAM_CACHE_DIR`` when it cannot be created.
    """
    current = jax.config.jax_compilation_cache_dir  # type: ignore[attr-defined]  # jax.config's options are dynamic
    if current:
        return str(current)
    p = Path(path) if path is not None else default_cache_dir()
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(
            f"{p}: cannot create the compilation cache directory ({e.strerror}); "
            f"set {CACHE_ENV} to a writable directory or pass --no-cache"
        ) from None
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    jax.config.update("jax_compilation_cache_dir", str(p))
    _replace_damaged_entries()
    return str(p)


def _replace_damaged_entries() -> None:
    """Make an entry of JAX's cache that cannot be read (truncated, corrupt) be replaced.

    JAX warns of such an entry and compiles the program, but does not write it again (an entry
    of that key exists), so every later run would compile it too. Wrapped here: an entry whose
    read fails is deleted before JAX recompiles, so the fresh executable is written in its place
    and the next run loads it. A JAX without these internals keeps its own behaviour.
    """
    try:
        from jax._src import compilation_cache as cc
        from jax._src import lru_cache
    except ImportError:  # pragma: no cover - another JAX layout
        return
    get = getattr(cc, "get_executable_and_time", None)
    if get is None or getattr(get, "_nanoslam_heals", False):
        return

    @functools.wraps(get)
    def get_or_delete(cache_key, compile_options, backend, *args, **kwargs):
        try:
            return get(cache_key, compile_options, backend, *args, **kwargs)
        except Exception as e:
            verification = getattr(cc, "CacheVerificationError", ())
            cache = cc._get_cache(backend) if hasattr(cc, "_get_cache") else None
            root = getattr(cache, "path", None)
            if root is not None and not isinstance(e, verification):
                for suffix in (
                    getattr(lru_cache, "_CACHE_SUFFIX", "-cache"),
                    getattr(lru_cache, "_ATIME_SUFFIX", "-atime"),
                ):
                    try:
                        Path(str(root / f"{cache_key}{suffix}")).unlink(missing_ok=True)
                    except OSError:
                        pass
            raise  # JAX warns and compiles; its write then finds no entry and keeps the new one

    get_or_delete._nanoslam_heals = True  # type: ignore[attr-defined]
    cc.get_executable_and_time = get_or_delete


# --------------------------------------------------------------------------- traced programs

#: Bumped when the layout of the ``exported/`` entries changes.
_EXPORT_FORMAT = "nanoslam-export-2"
#: Programs :func:`compile_program` compiled in this process, by entry path (the key).
_COMPILED: dict[Path, Callable] = {}


# --------------------------------------------------------------------------- compiled code in memory

#: :func:`release_programs` drops this process's compiled programs once its memory mappings reach
#: this fraction of the kernel's limit.
MAP_FRACTION = 0.5

#: In-process dicts of compiled programs (registered with :func:`program_cache`).
_PROGRAM_CACHES: list[dict] = [_COMPILED]


def program_cache(programs: dict) -> dict:
    """Register ``programs``, a module's dict of compiled programs, for :func:`release_programs`
    to empty; returns it (``_PROGRAMS = program_cache({})``)."""
    _PROGRAM_CACHES.append(programs)
    return programs


def memory_maps() -> Optional[tuple[int, int]]:
    """``(regions, limit)``: the memory regions this process maps and the kernel's limit on them
    (``vm.max_map_count``, 65530 unless raised); None where ``/proc`` does not tell (not Linux)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            regions = sum(1 for _ in f)
    except OSError:
        return None
    try:
        limit = int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        limit = 65530
    return regions, limit


def release_programs(fraction: float = MAP_FRACTION) -> bool:
    """Drop every compiled program this process holds (JAX's caches and this package's
    :func:`program_cache` dicts) if its memory regions have reached ``fraction`` of the kernel's
    limit; called before each compilation. Returns whether it dropped them.

    XLA:CPU maps each compiled program's code and data into many memory regions (a filter program
    takes hundreds to thousands) and keeps them while the executable lives. Linux limits a process
    to ``vm.max_map_count`` regions; when a new program cannot be mapped, LLVM aborts the whole
    process ("Unable to allocate section memory"), which the test suite did after about a hundred
    filter programs. A long sweep over static settings or a study compiles as many. A dropped
    program is compiled again (or loaded from the persistent cache) when next needed.

    Args:
        fraction: threshold as a fraction of the limit (0 drops unconditionally).
    """
    use = memory_maps()
    if fraction > 0 and (use is None or use[0] < fraction * use[1]):
        return False
    for programs in _PROGRAM_CACHES:
        programs.clear()
    jax.clear_caches()
    gc.collect()
    return True


@functools.lru_cache(maxsize=1)
def _environment_digest() -> str:
    """Hash of the code a trace runs: this package's source files and every installed
    distribution's name and version (:func:`program_key` adds JAX's configuration, the static
    settings and the arguments). A dependency installed in editable mode and edited in place keeps
    its version, so it is not seen: clear the cache or pass ``--no-cache`` while editing one."""
    h = hashlib.sha256(_EXPORT_FORMAT.encode())
    package = Path(__file__).resolve().parents[1]
    for f in sorted(package.rglob("*.py")):
        h.update(str(f.relative_to(package)).encode() + b"\0" + f.read_bytes() + b"\0")
    dists = sorted({(d.metadata["Name"] or "", d.version) for d in importlib.metadata.distributions()})
    h.update(repr(dists).encode())
    return h.hexdigest()


def _plugin_modules(static: Any, args: tuple) -> set[str]:
    """The modules of the plug-ins a program traces: the classes of the model objects among the
    arguments (equinox modules: a motion model) and the functions of the registered method."""
    import equinox as eqx

    mods = {
        type(x).__module__
        for x in jax.tree.leaves(args, is_leaf=lambda x: isinstance(x, eqx.Module))
        if isinstance(x, eqx.Module)
    }
    method = getattr(static, "method", None)
    mods |= {
        f.__module__
        for f in (getattr(method, a, None) for a in ("proposal", "init", "step", "shardable"))
        if f is not None and getattr(f, "__module__", None)
    }
    package = __name__.split(".")[0]
    return {m for m in mods if m != package and not m.startswith(package + ".")}


def _plugin_digest(static: Any, args: tuple) -> Optional[str]:
    """Hash of the source files of the plug-ins outside this package that a program traces (a
    user's motion model or method), or None when one has no source file to hash (defined in an
    interactive session): such a program is not kept in the traced-program cache."""
    h = hashlib.sha256()
    for name in sorted(_plugin_modules(static, args)):
        module = sys.modules.get(name)
        path = getattr(module, "__file__", None)
        if not path or not Path(path).is_file():
            return None
        h.update(name.encode() + b"\0" + Path(path).read_bytes() + b"\0")
    return h.hexdigest()


def program_key(fn: Callable, static: Any, args: tuple) -> Optional[str]:
    """The key of the traced program ``fn(static, *args)`` in the ``exported/`` cache, or None
    when it must not be cached (a plug-in without a source file, :func:`_plugin_digest`).

    Args:
        fn: the jitted function (its module and name enter the key).
        static: its static first argument (its ``repr`` enters the key: a frozen dataclass).
        args: the traced arguments (their tree structure, shapes, dtypes and placement).
    """
    plugins = _plugin_digest(static, args)
    if plugins is None:
        return None
    leaves, tree = jax.tree.flatten(args)
    config = sorted((k, repr(v)) for k, v in jax.config.values.items() if "cache" not in k and "log" not in k)
    h = hashlib.sha256(_environment_digest().encode())
    for part in (
        f"{getattr(fn, '__module__', '')}.{getattr(fn, '__qualname__', repr(fn))}",
        repr(static),
        str(tree),
        repr(config),
        repr([(str(jax.typeof(x)), repr(getattr(x, "sharding", None))) for x in leaves]),
        repr(jax.devices()),
        plugins,
    ):
        h.update(part.encode() + b"\0")
    return h.hexdigest()[:40]


def _exported_dir() -> Optional[Path]:
    """Where traced programs are kept: ``exported/`` in the cache directory in use (None: no cache)."""
    cache = jax.config.jax_compilation_cache_dir  # type: ignore[attr-defined]  # jax.config's options are dynamic
    return Path(cache) / "exported" if cache else None


# An entry of ``exported/`` is ``_MAGIC``, the length of its header (8 bytes, big-endian), the header
# (JSON: format, key, input tree, output tree, the program's SHA-256) and the program as
# ``jax.export`` serialises it. Reading one parses JSON and JAX's serialised module; nothing in it
# is imported, unpickled or called.
_MAGIC = b"nanoslam-jax exported program\n"


class _Unkeepable(Exception):
    """An output tree with a node that :func:`_describe_tree` cannot write down as plain data."""


def _subtrees(tree: jax.tree_util.PyTreeDef, path: tuple = ()):
    """Every subtree of ``tree`` that is not a leaf, with its path of child indices, outermost first."""
    if tree.node_data() is None:
        return
    yield path, tree
    for i, child in enumerate(tree.children()):
        yield from _subtrees(child, path + (i,))


def _namedtuple_class(name: str) -> type[Any]:
    """The NamedTuple class ``module:qualname`` of a module this process has already imported,
    found in the module's and classes' own namespaces: nothing is imported or run."""
    module_name, _, qualname = name.partition(":")
    module = sys.modules.get(module_name)
    if module is None or not qualname:
        raise ValueError(f"{name}: no such module in this process")
    obj: Any = module
    for part in qualname.split("."):
        obj = vars(obj).get(part)
        if obj is None:
            raise ValueError(f"{name}: not found")
    if not (
        isinstance(obj, type)
        and issubclass(obj, tuple)
        and any(isinstance(vars(c).get("_fields"), tuple) for c in obj.__mro__)
    ):
        raise ValueError(f"{name}: not a NamedTuple")
    return obj


def _describe_tree(tree: jax.tree_util.PyTreeDef, inputs: dict) -> Any:
    """``tree`` as plain data (JSON): ``"*"`` for a leaf, ``{"input": path}`` for a subtree equal to
    the input tree's subtree at ``path`` (the filter state a program returns), and otherwise
    ``{"node": kind, "children": [...]}`` for tuples, lists, None, dicts with string keys
    (``"keys"``) and NamedTuples (``"class": "module:qualname"``).

    Raises:
        _Unkeepable: for any other node (an equinox module or custom pytree not among the inputs).
    """
    node = tree.node_data()
    if node is None:
        return "*"
    if tree in inputs:
        return {"input": list(inputs[tree])}
    kind, aux = node
    children = [_describe_tree(c, inputs) for c in tree.children()]
    if kind in (tuple, list, type(None)) and aux is None:
        return {"node": kind.__name__, "children": children}
    if kind is dict and all(isinstance(k, str) for k in aux):
        return {"node": "dict", "keys": list(aux), "children": children}
    if issubclass(kind, tuple) and hasattr(kind, "_fields") and aux is None:
        name = f"{kind.__module__}:{kind.__qualname__}"
        try:
            found = _namedtuple_class(name)
        except ValueError:
            found = None
        if found is kind:
            return {"node": "namedtuple", "class": name, "children": children}
    raise _Unkeepable(f"{kind.__module__}.{kind.__qualname__}")


_BUILTIN_NODES = {"tuple": tuple, "list": list, "NoneType": type(None)}


def _rebuild_tree(desc: Any, in_tree: jax.tree_util.PyTreeDef) -> jax.tree_util.PyTreeDef:
    """The tree :func:`_describe_tree` wrote down; ValueError (or a TypeError, KeyError, ...) for
    anything else."""
    if desc == "*":
        return jax.tree.structure(0)
    if not isinstance(desc, dict):
        raise TypeError("not a tree description")
    if "input" in desc:
        sub = in_tree
        for i in desc["input"]:
            sub = sub.children()[int(i)]
        return sub
    kind = desc["node"]
    children = [_rebuild_tree(c, in_tree) for c in desc["children"]]
    if kind in _BUILTIN_NODES:
        node = (_BUILTIN_NODES[kind], None)
    elif kind == "dict":
        keys = desc["keys"]
        if not all(isinstance(k, str) for k in keys) or keys != sorted(keys) or len(keys) != len(children):
            raise ValueError("bad dict keys")
        node = (dict, keys)
    elif kind == "namedtuple":
        cls = _namedtuple_class(desc["class"])
        if len(cls._fields) != len(children):
            raise ValueError(f"{desc['class']}: {len(children)} children for {len(cls._fields)} fields")
        node = (cls, None)
    else:
        raise ValueError(f"unknown node {kind!r}")
    return jax.tree_util.PyTreeDef.from_node_data_and_children(jax.tree_util.default_registry, node, children)


def _read_exported(path: Path, key: str, in_tree: jax.tree_util.PyTreeDef, leaves: list):
    """The program and output tree kept at ``path``, or None when there is none or it does not hold
    exactly what ``key`` names for these arguments (a damaged, foreign or planted file): the caller
    then traces afresh and overwrites it."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    try:
        if not data.startswith(_MAGIC):
            return None
        start = len(_MAGIC) + 8
        size = int.from_bytes(data[len(_MAGIC) : start], "big")
        header = json.loads(data[start : start + size].decode("utf-8"))
        blob = data[start + size :]
        if (
            header.get("format") != _EXPORT_FORMAT
            or header.get("key") != key
            or header.get("in_tree") != str(in_tree)
            or header.get("sha256") != hashlib.sha256(blob).hexdigest()
        ):
            return None
        out_tree = _rebuild_tree(header["out_tree"], in_tree)
        exported = jax.export.deserialize(bytearray(blob))
        avals = [(tuple(a.shape), str(a.dtype)) for a in exported.in_avals]
        if (
            avals != [(tuple(jax.typeof(x).shape), str(jax.typeof(x).dtype)) for x in leaves]
            or len(exported.out_avals) != out_tree.num_leaves
        ):
            return None
        return exported, out_tree
    except Exception:  # anything unreadable is a miss
        return None


def _write_exported(path: Path, key: str, in_tree, exported, out_tree) -> None:
    """Keep the program at ``path`` (atomically, readable by all), or raise :class:`_Unkeepable`
    when its output tree cannot be written down as plain data."""
    blob = bytes(exported.serialize())
    header = json.dumps(
        {
            "format": _EXPORT_FORMAT,
            "key": key,
            "in_tree": str(in_tree),
            "out_tree": _describe_tree(out_tree, {t: p for p, t in reversed(list(_subtrees(in_tree)))}),
            "sha256": hashlib.sha256(blob).hexdigest(),
        }
    ).encode("utf-8")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(_MAGIC + len(header).to_bytes(8, "big") + header + blob)
        os.chmod(tmp, 0o644)  # as JAX's own entries: a shared cache directory stays readable
        os.replace(tmp, path)  # atomic: concurrent runs never read half an entry
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def compile_program(
    fn: jax.stages.Wrapped, static: Any, *args: Any, label: str = "program", segments: int = 0, batch: int = 1
) -> Callable:
    """``fn.lower(static, *args).compile()``, loading the traced program from the cache when it can.

    Without a cache directory (:func:`enable_compile_cache` not called, or ``--no-cache``), or for
    a program split over several devices (``static.devices > 1``), this is exactly
    ``fn.lower(static, *args).compile()``. Otherwise the lowered program is exported
    (:mod:`jax.export`) to ``exported/`` under :func:`program_key`, or read from there, and
    compiled (the XLA layer of the cache then loads the executable). The result is the same
    program: outputs are identical bit for bit (``tests/unit/lib/test_cache.py``). An entry is data only
    (JAX's serialised module and a JSON header); one that does not load or does not match the key
    and the arguments is traced afresh and overwritten. A program whose output holds a node other
    than tuples, lists, dicts, None, NamedTuples and subtrees of its inputs is compiled but not
    kept. The key covers the package's files as they are on disk: a script that swaps code in at
    run time must not enable the cache.

    Args:
        fn: a ``jax.jit`` function whose first argument is static.
        static: that static argument.
        *args: example arguments (their shapes, dtypes and placement are those of every call).
        label, segments, batch: what the program is, for the watcher of :func:`watch_compiles`
            (:func:`watched_compile`): a name, the log segments per call, the runs side by side.

    Returns:
        A callable taking ``*args`` and returning ``fn``'s output.
    """
    release_programs()
    directory = _exported_dir()
    watched = functools.partial(watched_compile, label, static, args, segments=segments, batch=batch)
    if directory is None or getattr(static, "devices", 1) > 1:
        with watched():
            return fn.lower(static, *args).compile()
    key = program_key(fn, static, args)
    if key is None:
        with watched():
            return fn.lower(static, *args).compile()
    path = directory / f"{key}.bin"
    if path in _COMPILED:  # this process compiled it already (as jit's own in-memory caches would)
        return _COMPILED[path]
    with watched(expect_load=path.is_file()):
        return _trace_or_load(fn, static, args, path, key)


def _trace_or_load(fn: jax.stages.Wrapped, static: Any, args: tuple, path: Path, key: str) -> Callable:
    """:func:`compile_program` past its in-process check: the program loaded from ``path`` or
    traced, kept there and compiled."""
    leaves, in_tree = jax.tree.flatten(args)
    compiled = None
    loaded = _read_exported(path, key, in_tree, leaves)
    if loaded is not None:
        exported, out_tree = loaded
        try:
            compiled = jax.jit(exported.call).lower(*leaves).compile()
        except Exception:  # a program this JAX cannot run: a miss like any other
            compiled = None
    if compiled is None:
        box = {}

        def flat(*flat_args):
            out = fn(static, *jax.tree.unflatten(in_tree, flat_args))
            out_leaves, box["tree"] = jax.tree.flatten(out)
            return out_leaves

        try:
            # Custom calls (LAPACK kernels of lineax's QR, ...) are allowed although their ABI is not
            # guaranteed across jaxlib versions: an entry is only ever read back by the very same
            # versions (every installed distribution's version is in its key).
            exported = jax.export.export(
                jax.jit(flat), disabled_checks=[jax.export.DisabledSafetyCheck.custom_call("ALL")]
            )(*leaves)
        except Exception:  # a program jax.export cannot hold: compile it directly (executable layer only)
            compiled_direct = fn.lower(static, *args).compile()
            _COMPILED[path] = compiled_direct
            return compiled_direct
        out_tree = box["tree"]
        try:
            _write_exported(path, key, in_tree, exported, out_tree)
        except (_Unkeepable, ImportError, OSError):  # a tree not kept as data, no serializer, unwritable
            pass
        compiled = jax.jit(exported.call).lower(*leaves).compile()

    def call(*call_args):
        return jax.tree.unflatten(out_tree, compiled(*jax.tree.leaves(call_args)))

    _COMPILED[path] = call
    return call
