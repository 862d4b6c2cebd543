"""The Hydra side of training: where the configs live, the ``level`` options taken from evaaa, and the values the
training code derives from a composed config (observation keys, env overrides, curriculum stages).

Every level and testbed evaaa lists is a ``level=<name>`` option without a file to keep in sync: :func:`register_levels`
stores one ``{name, overrides}`` node per name in Hydra's ConfigStore.  Files in ``conf/level/`` add options
beside them (``curriculum.yaml``; ``file.yaml``, a level from the user's own YAML file, ``level=file
level.file=path/to/my.yaml``) and would take precedence over a registered name.
"""

from __future__ import annotations

import contextlib
import copy
import difflib
import re
import sys
import tempfile
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from hydra.core.config_store import ConfigStore
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from omegaconf import DictConfig, OmegaConf, open_dict

import evaaa
from evaaa.records import DiskError
from evaaa.sensors import SENSORS, resolve_modalities

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def register_levels() -> None:
    """Make ``level=<name>`` available for every name in ``evaaa.LEVELS + evaaa.TESTBEDS``, and the ``level_stem``
    resolver that names a ``level=file`` run after its file."""
    if not OmegaConf.has_resolver("level_stem"):
        OmegaConf.register_new_resolver("level_stem", lambda path: Path(str(path)).stem)
    store = ConfigStore.instance()
    for name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
        store.store(group="level", name=name, node={"name": name, "overrides": {}})


def register_launchers() -> None:
    """Make ``hydra/launcher=ray_cluster`` (evaaa's launcher plugin, hydra_plugins/evaaa_ray_launcher) known to
    Hydra. Hydra finds launchers by walking the ``hydra_plugins`` namespace's folders, which misses the plugin of an
    editable install (its folder is reached through setuptools' import hook, not a path); registering it is Hydra's
    way for that (``Plugins.register``) and harmless where the walk found it."""
    from hydra.core.plugins import Plugins

    from hydra_plugins.evaaa_ray_launcher.ray_launcher import RayLauncher

    Plugins.instance().register(RayLauncher)


@dataclass(frozen=True)
class Stage:
    """One level trained for ``budget`` env steps; a direct run has one stage, a curriculum several."""

    index: int
    level: str
    budget: int


def stages(cfg: DictConfig) -> list[Stage]:
    """The stages of a run: the level alone, or the curriculum's levels in order (default: ``evaaa.LEVELS``)."""
    if "stages" not in cfg.level:
        # a level from the user's file is made loadable by its name (the file's stem), which the run's files carry
        name = evaaa.register_level(cfg.level.file) if "file" in cfg.level else cfg.level.name
        return [Stage(0, name, int(cfg.total_steps))]
    names = list(cfg.level.stages) if cfg.level.stages is not None else list(evaaa.LEVELS)
    unknown = [n for n in names if n not in (*evaaa.LEVELS, *evaaa.TESTBEDS)]
    if unknown or not names:
        raise ValueError(f"curriculum stages must be names from evaaa.LEVELS/TESTBEDS, got {names}")
    return [Stage(i, name, int(cfg.level.stage_steps)) for i, name in enumerate(names)]


def observation_keys(cfg: DictConfig) -> tuple[str, ...]:
    """The enabled observation keys, in evaaa's canonical order."""
    known = resolve_modalities(list(SENSORS))  # this package's sensors and any the user's code has defined
    unknown = set(cfg.modality.enabled) - set(known)
    if unknown:
        raise ValueError(f"modality.enabled names unknown keys {sorted(unknown)}; known: {', '.join(known)}")
    keys = tuple(k for k in known if cfg.modality.enabled.get(k, False))
    if not keys:
        raise ValueError(f"modality '{cfg.modality.name}' enables no observation key")
    return keys


def env_overrides(cfg: DictConfig) -> dict[str, Any]:
    """Level-field overrides for ``evaaa.make_env``: the level option's, the reward's, then ``env.overrides``."""
    # a reward option names a level reward function, or lists the level's reward fields it sets under ``overrides``
    reward = cfg.reward.get("overrides") or {"name": cfg.reward.name}
    layers = [
        OmegaConf.to_container(cfg.level.overrides, resolve=True),
        {"reward": reward},
        OmegaConf.to_container(cfg.env.overrides, resolve=True),
    ]
    return OmegaConf.to_container(OmegaConf.merge(*layers))


# ------------------------------------------------------------------------------------------------- command line
class ConfigError(ValueError):
    """A training command line or composed config is refused; the message is one line naming the key."""


#: keys whose default is null, and what else they take (a null default says nothing about the type)
NULLABLE = {
    "max_minutes": (float, int),
    "max_cpu_minutes": (float, int),
    "threads": (int,),
    "level.stages": (list,),
    "algo.lstm": (dict,),
    "algo.sequence_length": (int,),
}
#: free-form nodes: any key below them is a level field (checked by evaaa when the env is made)
FREE_FORM = ("env.overrides", "level.overrides")
#: config groups of conf/ that are not training's: ``scripts/reproduce.py protocol=<name>`` reads conf/protocol/
NOT_TRAINING = ("hydra", "protocol")


def _at_least(low: float, text: str) -> tuple[Any, str]:
    return (lambda v: v >= low), text


_POSITIVE = _at_least(1, "an integer >= 1")
_NATURAL = _at_least(0, "an integer >= 0")
_POSITIVE_NUMBER = ((lambda v: v > 0), "a number > 0")
_SHARE = ((lambda v: 0 <= v <= 1), "a number from 0 to 1")
_DISCOUNT = ((lambda v: 0 < v <= 1), "a number > 0 and <= 1")
#: bounds beyond a key's type, checked before anything is written: ``(test, what is allowed)``.  A budget of 0 or
#: less would create the run folder and then fail (or divide by zero) in the training loop
LIMITS: dict[str, tuple[Any, str]] = {
    "seed": _NATURAL,
    "total_steps": _POSITIVE,
    "max_minutes": _POSITIVE_NUMBER,
    "threads": _POSITIVE,
    "env.num_envs": _POSITIVE,
    "eval.every": (_NATURAL[0], "an integer >= 0 (0: never)"),
    "eval.episodes": _POSITIVE,
    "eval.seed_offset": _NATURAL,
    "checkpoint.every": (_NATURAL[0], "an integer >= 0 (0: only at the end)"),
    "log_every": _POSITIVE,
    "progress_window": _POSITIVE,
    "progress_seconds": _POSITIVE_NUMBER,
    "level.stage_steps": _POSITIVE,
}
#: bounds of the algorithms' keys, by the key's last name (``algo.lr``, ``algo.actor.lr``)
ALGO_LIMITS: dict[str, tuple[Any, str]] = {
    **dict.fromkeys(
        (
            "frames_per_batch",
            "num_minibatches",
            "epochs",
            "batch_size",
            "buffer_size",
            "frame_stack",
            "sequence_length",
            "horizon",
            "target_update_every",
            "updates_per_step",
            "dense",
            "recurrent",
            "hidden",
            "stochastic",
            "classes",
            "bins",
            "mlp_layers",
        ),
        _POSITIVE,
    ),
    "learning_starts": _NATURAL,
    "eps_anneal_updates": _POSITIVE,
    **dict.fromkeys(("lr", "replay_ratio"), _POSITIVE_NUMBER),
    **dict.fromkeys(("gamma", "gae_lambda", "lmbda"), _DISCOUNT),
    **dict.fromkeys(("eps_start", "eps_end", "consume_share", "terminal_share", "tau", "unimix"), _SHARE),
}


def limit_of(full: str) -> tuple[Any, str] | None:
    """The bounds of the key ``full`` (dotted), if it has any beyond its type."""
    if full in LIMITS:
        return LIMITS[full]
    return ALGO_LIMITS.get(full.rpartition(".")[2]) if full.startswith("algo.") else None


#: meanings of the keys that name a group's option, and of those of the ``level=<name>`` options that
#: :func:`register_levels` stores
GROUP_KEYS = {
    "algo.name": "the algorithm (algo=<name> chooses it)",
    "modality.name": "the set of observation keys (modality=<name> chooses it)",
    "modality.enabled": "the observation keys the agent sees",
    "reward.name": "the reward function (reward=<name> chooses it)",
    "logger.backend": "where training metrics go (logger=<name> chooses it)",
    "level.name": "the level or testbed trained on (level=<name> chooses it)",
    "level.file": "the YAML file of your own level (level=file level.file=path/to/my.yaml)",
    "level.overrides": "level-field changes for this level, e.g. ++level.overrides.episode.max_steps=2000",
}


def _type_text(types: tuple[type, ...], plural: bool = False) -> str:
    if plural:
        names = {bool: "true/false values", int: "integers", float: "numbers", str: "strings"}
    else:
        names = {
            bool: "true or false",
            int: "an integer",
            float: "a number",
            str: "a string",
            list: "a list [a,b]",
            dict: "a mapping {a: 1}",
        }
    if float in types:  # an integer is a number too
        types = tuple(t for t in types if t is not int)
    return " or ".join(names[t] for t in types)


def _allowed_types(default: Any) -> tuple[type, ...]:
    if isinstance(default, bool):
        return (bool,)
    if isinstance(default, int):
        return (int,)
    if isinstance(default, float):
        return (float, int)
    if isinstance(default, str):
        return (str,)
    return (type(default),)


def _matches(value: Any, types: tuple[type, ...]) -> bool:
    if isinstance(value, bool) and bool not in types:
        return False  # true is not a number here
    return isinstance(value, types)


def _show(value: Any) -> str:
    if OmegaConf.is_config(value):
        value = OmegaConf.to_container(value)
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return "[" + ",".join(_show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_show(v)}" for k, v in value.items()) + "}"
    return str(value)


def validate(cfg: DictConfig, defaults: DictConfig, path: str = "", typed: dict[str, str] | None = None) -> None:
    """Every value of a composed training config has the type of its default (from the same groups, without the
    command line's values) and lies within its :func:`limit_of`: ``total_steps=abc``, ``total_steps=-5`` or
    ``eval.sample=maybe`` is refused before any work, as is a key the defaults do not have (``+totl_steps=5`` would
    otherwise be ignored).  ``typed``: the text given for each key on the command line, which the message quotes
    (YAML reads ``1e3`` as 1000.0 and ``3_2`` as 32).  Raises :class:`ConfigError`."""
    typed = typed or {}

    def shown(full: str, value: Any) -> str:
        return typed.get(full, _show(value))

    for key in cfg.keys() if OmegaConf.is_dict(cfg) else ():
        full = f"{path}{key}"
        if full.startswith(FREE_FORM):
            continue
        if key not in defaults.keys():  # ``in`` alone is false for a mandatory value (``???``) such as level.file
            allowed = ", ".join(f"{path}{k}" for k in defaults.keys())
            raise ConfigError(f"unknown key '{full}'; keys here: {allowed} (see --help)")
        if OmegaConf.is_interpolation(cfg, key):
            continue  # a reference to another key: that key is checked
        if OmegaConf.is_missing(defaults, key):
            continue  # no default to take a type from (level.file: evaaa checks the file when the env is made)
        try:  # a reference (run.name, level.stage_steps): a value given instead has the type of what it refers to
            default_node = defaults[key]
        except Exception:  # noqa: BLE001  (a reference only a running job resolves)
            continue
        value, default = cfg[key], default_node
        if default is None:
            types = NULLABLE.get(full)
            if types is None or value is None:
                continue
        elif value is None:
            if full in NULLABLE:
                continue
            raise ConfigError(
                f"{full}={shown(full, value)}: expected {_type_text(_allowed_types(default))} "
                f"(default {_show(default)})"
            )
        elif OmegaConf.is_dict(default):
            if not OmegaConf.is_dict(value):
                raise ConfigError(f"{full}={_show(value)}: expected a mapping of {', '.join(default.keys())}")
            validate(value, default, f"{full}.", typed)
            continue
        elif OmegaConf.is_list(default):
            types = (list,)
        else:
            types = _allowed_types(default)
        plain = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
        if not _matches(plain, tuple(list if t is list else dict if t is dict else t for t in types)):
            read_as = ""
            if full in typed and typed[full] != _show(value) and not isinstance(plain, (list, dict)):
                read_as = f"; YAML reads it as {_show(value)}"  # 1e3 is a float to YAML, 3_2 the integer 32
            if str in types and not isinstance(plain, str):
                read_as += f": quote it to keep the text, e.g. '{full}=\"{shown(full, value)}\"'"
            elif int in types and float not in types and isinstance(plain, float) and plain.is_integer():
                read_as += f": write it as an integer, e.g. {full}={int(plain)} or {full}={int(plain):_}"
            raise ConfigError(
                f"{full}={shown(full, value)}: expected {_type_text(types)}"
                + ("" if default is None else f" (default {_show(default)})")
                + read_as
            )
        bounds = limit_of(full)
        if bounds is not None and not isinstance(plain, (list, dict, bool, str)) and not bounds[0](plain):
            raise ConfigError(
                f"{full}={shown(full, value)}: expected {bounds[1]}"
                + ("" if default is None else f" (default {_show(default)})")
            )
        if (
            OmegaConf.is_list(default)
            and len(default)
            and not isinstance(default[0], (list, dict))
            and not OmegaConf.is_config(default[0])
        ):
            item_types = _allowed_types(default[0])
            bad = [v for v in plain if not _matches(v, item_types)]
            if bad:
                raise ConfigError(
                    f"{full}={shown(full, value)}: expected a list of {_type_text(item_types, plural=True)} "
                    f"(default {_show(default)}), got {_show(bad[0])}"
                )


def _group_of(override: Override, groups: set[str]) -> bool:
    """Whether an override chooses a config group option (``algo=dqn``, ``hydra/launcher=basic``)."""
    key = override.key_or_group.split("@")[0]
    return "/" in key or key in groups


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split("\n")[0].split())


_DEFAULTS: dict[tuple[str, ...], DictConfig] = {}


def compose_checked(overrides: list[str], values: bool = True) -> DictConfig:
    """The training config of one job composed as ``scripts/train.py`` would, :func:`validate`-d and (``values``)
    :func:`check_values`-d.  Call it inside ``hydra.initialize_config_dir(CONF_DIR)``, after
    :func:`register_levels`.  Raises :class:`ConfigError` naming the key."""
    from hydra import compose
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import MissingConfigException, OverrideParseException

    loader = GlobalHydra.instance().config_loader()
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except OverrideParseException as err:
        raise ConfigError(f"{_one_line(err)} (in {' '.join(overrides)}; lists are key=[a,b])") from None
    groups = set(loader.list_groups(""))
    chosen = [o.input_line for o in parsed if _group_of(o, groups)]
    for o in parsed:
        group = o.key_or_group.split("@")[0]
        if group in NOT_TRAINING[1:]:
            raise ConfigError(
                f"{o.input_line}: {group} is not a key of train.py (scripts/reproduce.py "
                f"{group}=<name> runs a protocol)"
            )
        if _group_of(o, groups) and o.value() is not None and not isinstance(o.value(), list):
            options = loader.get_group_options(group)
            text = _typed_text(o)  # YAML reads level=3_2 as the integer 32: the message quotes what was typed
            if options and (not isinstance(o.value(), str) or o.value() not in options):
                close = difflib.get_close_matches(text, options, n=1, cutoff=0.6)
                hint = f" (did you mean {group}={close[0]}?)" if close else ""
                raise ConfigError(f"{o.input_line}: no option '{text}' in {group}{hint}; allowed: {', '.join(options)}")
    key = tuple(chosen)
    if key not in _DEFAULTS:  # a sweep composes the same groups' defaults again and again
        try:
            _DEFAULTS[key] = compose("config", overrides=chosen)
        except MissingConfigException as err:
            raise ConfigError(_one_line(err)) from None
    defaults = _DEFAULTS[key]
    try:
        cfg = compose("config", overrides=list(overrides))
    except Exception as err:  # noqa: BLE001  (Hydra's composition errors have no common narrower base)
        cause = err.__cause__
        full_key = getattr(cause, "full_key", None)
        if full_key and "not in" in str(cause):
            parent = full_key.rpartition(".")[0]
            node = OmegaConf.select(defaults, parent) if parent else defaults
            keys = ", ".join(
                f"{parent + '.' if parent else ''}{k}" for k in (node.keys() if OmegaConf.is_dict(node) else ())
            )
            if node is None:
                raise ConfigError(
                    f"unknown key '{full_key}': {parent} is null with these options; set it whole, "
                    f"e.g. {parent}={{{full_key.rpartition('.')[2]}: ...}}"
                ) from None
            if OmegaConf.is_dict(node) and not len(node):  # an empty mapping (env.overrides) takes new keys
                line = next((o.input_line for o in parsed if o.key_or_group.startswith(full_key)), full_key)
                raise ConfigError(f"'{full_key}' is not in {parent} yet: add it with ++{line.lstrip('+')}") from None
            raise ConfigError(f"unknown key '{full_key}'; keys here: {keys} (see --help)") from None
        raise ConfigError(_one_line(err)) from None
    typed = typed_values(parsed)
    validate(cfg, defaults, typed=typed)
    if values:
        check_values(cfg, typed)
    _LAST[:] = [cfg, defaults]
    return cfg


def _typed_text(override: Override) -> str:
    """The value of ``override`` as typed on the command line."""
    return override.input_line.partition("=")[2]


def typed_values(parsed: list[Override]) -> dict[str, str]:
    """The text typed for each key of the command line, by dotted key (``++total_steps=1e3`` -> ``1e3``)."""
    return {o.key_or_group.lstrip("+"): _typed_text(o) for o in parsed}


def check_values(cfg: DictConfig, typed: dict[str, str] | None = None) -> None:
    """What a composed config's types and bounds do not say, checked before anything is written: the device exists
    here, the env's backend is known (and installed), the curriculum names levels, the algorithm accepts its settings (``check_config`` of its module, if it
    has one), and DreamerV3's GPU size is not started on a CPU unless asked for by name.  Raises
    :class:`ConfigError`."""
    from .algos import algorithm
    from .runtime import DeviceError, resolve_device

    try:
        device = resolve_device(cfg.device)
    except DeviceError as err:
        raise ConfigError(str(err)) from None
    backend = cfg.env.get("backend", "cpu")
    if backend not in evaaa.BACKENDS:
        raise ConfigError(f"env.backend={_show(backend)}: expected one of {', '.join(evaaa.BACKENDS)}")
    if backend == "warp":
        from evaaa import mjwarp

        if not mjwarp.available():
            raise ConfigError(f"env.backend=warp: {mjwarp.INSTALL_HINT}")
    if "stages" in cfg.level and cfg.level.stages is not None:
        text = (typed or {}).get("level.stages")
        names = [str(n) for n in cfg.level.stages]
        if text is not None:  # the names as typed: YAML reads [1-1,3_2] as ["1-1", 32]
            with contextlib.suppress(yaml.YAMLError):
                raw = yaml.load(text, Loader=yaml.BaseLoader)
                names = raw if isinstance(raw, list) and len(raw) == len(names) else names
        unknown = [n for n in names if n not in (*evaaa.LEVELS, *evaaa.TESTBEDS)]
        if unknown or not names:
            raise ConfigError(
                f"level.stages={text or _show(cfg.level.stages)}: "
                + (f"'{unknown[0]}' is not a level" if unknown else "expected at least one level")
                + f"; allowed: {', '.join((*evaaa.LEVELS, *evaaa.TESTBEDS))}"
            )
    module = algorithm(cfg.algo.name)
    check = getattr(module, "check_config", None)
    if check is not None:
        problem = check(cfg)
        if problem:
            raise ConfigError(problem)
    if (
        cfg.algo.name == "dreamer"
        and cfg.algo.get("size") == "S"
        and device.type == "cpu"
        and str(cfg.device).strip().lower() == "auto"
    ):
        raise ConfigError(CPU_DREAMER)


#: why ``algo=dreamer`` stops on a machine without a GPU, and what to type instead (docs/training.md, "DreamerV3")
CPU_DREAMER = (
    "algo=dreamer is DreamerV3 size S, a GPU size: no CUDA device here, and on a CPU one of its gradient "
    "steps takes 10-80 s (days for a level); algo=dreamer_xs is its CPU size, or add device=cpu to train "
    "size S on the CPU anyway"
)


_LAST: list[DictConfig] = []  # the last config compose_checked composed, and its defaults


def job_overrides(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The override lists of the jobs to check: one, or for a sweep (``-m seed=0,1 algo=dqn,ppo``) each value of each
    swept key once (the others at their first value), so that every value given is composed and checked."""
    from hydra.errors import OverrideParseException

    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except OverrideParseException as err:
        raise ConfigError(f"{_one_line(err)} (in {' '.join(overrides)}; lists are key=[a,b])") from None
    swept = {i: list(o.sweep_string_iterator()) for i, o in enumerate(parsed) if o.is_sweep_override()}
    if swept and not multirun:
        first = parsed[next(iter(swept))]
        raise ConfigError(
            f"{first.input_line}: several values make a sweep: add -m (--multirun); a list is "
            f"written {first.key_or_group}=[a,b]"
        )
    if not swept:
        return [list(overrides)]

    def line(i: int, value: str) -> str:
        return f"{parsed[i].get_key_element()}={value}"

    base = [
        line(i, values[0]) if i in swept else o.input_line
        for i, (o, values) in enumerate((o, swept.get(i, [])) for i, o in enumerate(parsed))
    ]
    jobs = [base]
    for i, values in swept.items():
        for value in values[1:]:
            jobs.append([*base[:i], line(i, value), *base[i + 1 :]])
    return jobs


def check_overrides(overrides: list[str], multirun: bool, values: bool = True) -> None:
    """Compose and check every job of :func:`job_overrides`; a job that differs from the first only in the value of
    a plain key (``seed=0,1,2``) is checked by setting that value in the first job's config, which is much faster
    than composing it again and gives the same verdict.  ``values=False``: keys and types only, not what depends on
    this machine (:func:`check_values`).  Raises :class:`ConfigError`."""
    jobs = job_overrides(overrides, multirun)
    compose_checked(jobs[0], values)
    first, defaults = _LAST
    from hydra.core.global_hydra import GlobalHydra

    groups = set(GlobalHydra.instance().config_loader().list_groups(""))
    parser = OverridesParser.create()
    for job in jobs[1:]:
        changed = [parser.parse_override(new) for new, old in zip(job, jobs[0]) if new != old]
        if len(changed) != 1 or _group_of(changed[0], groups) or changed[0].key_or_group.startswith("hydra"):
            compose_checked(job, values)
            continue
        trial = copy.deepcopy(first)
        with open_dict(trial):
            OmegaConf.update(trial, changed[0].key_or_group, changed[0].value(), force_add=True)
        validate(trial, defaults, typed=typed_values(changed))


def check_command_line(argv: list[str], doc: str = "") -> None:
    """``scripts/train.py``'s command line, before Hydra starts (and writes anything): ``--help`` prints
    :func:`help_text` and exits 0; a malformed value, unknown key or option prints one line naming it and exits 2.
    Every job of a sweep is composed and checked.  Hydra's other flags are Hydra's (``--hydra-help``, ``--info``)."""
    from hydra import initialize_config_dir
    from hydra._internal.utils import get_args_parser

    register_levels()
    args = get_args_parser().parse_args(argv)  # Hydra's own flags, parsed as Hydra will (a bad flag exits 2 here)
    if args.hydra_help or args.info or args.shell_completion or args.config_name or args.config_path or args.config_dir:
        return  # Hydra's own answers, or another config than conf/config.yaml: Hydra checks it
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        try:
            if args.help:
                print(help_text(args.overrides, "train.py", doc.split("\n\n")[0].replace("``", "")))
                raise SystemExit(0)
            check_overrides(args.overrides, args.multirun)
        except ConfigError as err:
            print(f"train.py: error: {err}", file=sys.stderr)
            raise SystemExit(2) from None
    root = Path(str(OmegaConf.select(_LAST[0], "run.root", default="runs")))
    try:
        check_writable(root)
    except DiskError as err:  # Hydra would make the run folder and end in a traceback
        print(f"train.py: {err}; nothing was written", file=sys.stderr)
        raise SystemExit(1) from None


def check_writable(folder: Path) -> None:
    """Raise :class:`~evaaa.records.DiskError` where ``folder`` (or, while it does not exist, the folder it would
    be made in) cannot take files: a real write, since root passes every permission check on a read-only disk."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        with tempfile.TemporaryDirectory(dir=existing, prefix=".write-test-"):
            pass
    except OSError as exc:
        raise DiskError(folder, exc) from None


# ------------------------------------------------------------------------------------------------- --help
_LINE = re.compile(r"^(?P<indent>\s*)(?P<key>[\w.-]+):(?P<rest>.*)$")


def comments(path: Path, prefix: str) -> dict[str, str]:
    """The trailing ``# comment`` of every ``key: value`` line of a YAML config file, by dotted key (``prefix`` is
    the file's package: ``algo.`` for conf/algo/*.yaml, nothing for the primary config and ``_global_`` files)."""
    text = path.read_text()
    if "# @package _global_" in text:
        prefix = ""
    found: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    last, column = None, -1  # the key whose comment a comment-only line at the same column continues
    for line in text.splitlines():
        if line.lstrip().startswith("#") and last is not None and line.index("#") == column:
            found[last] += " " + line.strip().lstrip("#").strip()
            continue
        last = None
        match = _LINE.match(line)
        if not match or line.lstrip().startswith(("#", "-")):
            continue
        indent = len(match["indent"])
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, match["key"]))
        value, _, comment = match["rest"].partition(" #")
        key = prefix + ".".join(k for _, k in stack)
        if comment.strip() and key not in found:
            found[key], last, column = comment.strip(), key, line.index(" #") + 1
    return found


def _config_files(choices: dict[str, Any]) -> list[tuple[Path, str]]:
    """The files a composition read, primary config first, with the package of each."""
    files = [(CONF_DIR / "config.yaml", "")]
    for group, option in choices.items():
        if option is None or group.startswith("hydra"):
            continue
        path, package = group.split("@")[0], (group.split("@")[1] if "@" in group else group)
        names = [option]
        while (CONF_DIR / path / f"{names[-1]}.yaml").is_file():  # an option may extend another (ppo_lstm: ppo)
            base = re.search(
                r"^defaults:\n\s+-\s+([\w-]+)\s*$", (CONF_DIR / path / f"{names[-1]}.yaml").read_text(), re.M
            )
            if base is None or base[1] in names:
                break
            names.append(base[1])
        files += [(CONF_DIR / path / f"{name}.yaml", f"{package}.") for name in names]
    return [(p, pkg) for p, pkg in files if p.is_file()]


def help_text(overrides: list[str], prog: str = "train.py", description: str = "") -> str:
    """``train.py --help``: the groups and their options, then every key of the config composed from ``overrides``
    (``--help algo=dqn`` shows DQN's keys) with its type, default and the meaning its config file gives it."""
    from hydra import compose
    from hydra.core.global_hydra import GlobalHydra

    loader = GlobalHydra.instance().config_loader()
    compose_checked(list(overrides), values=False)  # a bad override is refused as it would be without --help
    cfg = compose("config", overrides=list(overrides), return_hydra_config=True)
    choices = dict(cfg.hydra.runtime.choices)
    with open_dict(cfg):
        del cfg["hydra"]
    meanings = dict(GROUP_KEYS)
    for path, package in _config_files(choices):
        for key, text in comments(path, package).items():
            meanings.setdefault(key, text)
    lines = [
        f"usage: python scripts/{prog} [key=value ...]        (one run)",
        f"       python scripts/{prog} -m key=a,b ... [key=value ...]   (a sweep: one run per combination)",
        "",
    ]
    if description:
        lines += [*textwrap.wrap(" ".join(description.split()), width=114), ""]
    lines.append("groups (group=option; the config below is composed from the options chosen):")
    for group in sorted(g for g in loader.list_groups("") if g not in NOT_TRAINING):
        options = loader.get_group_options(group)
        lines += textwrap.wrap(
            f"{group}: {', '.join(options)} (now {choices.get(group)})",
            width=114,
            initial_indent="  ",
            subsequent_indent="      ",
            break_on_hyphens=False,
        )
    groups = set(loader.list_groups(""))
    lines += [
        "",
        "keys (key=value, nested keys dotted: eval.every=50000; lists key=[a,b]; values read as YAML; "
        "a key not listed needs ++key=value):",
    ]

    def walk(node: DictConfig, path: str) -> None:
        for key in node.keys():
            full = f"{path}{key}"
            if OmegaConf.is_interpolation(node, key):  # shown as written; its type is that of what it refers to
                value = node._get_node(key)._value()
                try:
                    kind = _kind(full, node[key])
                except Exception:  # noqa: BLE001  (a reference only a running job resolves)
                    kind = "reference"
            else:
                value = node[key]
                if OmegaConf.is_dict(value) and full in groups and not len(value):
                    continue  # a group whose option sets nothing (preset=none)
                if OmegaConf.is_dict(value) and len(value) and full not in FREE_FORM:
                    if full in meanings:  # what the keys below have in common
                        lines.append(f"  {full}.*:")
                        lines.extend(
                            textwrap.wrap(meanings[full], width=114, initial_indent=" " * 6, subsequent_indent=" " * 6)
                        )
                    walk(value, f"{full}.")
                    continue
                kind = _kind(full, value)
            lines.append(f"  {full}: {kind} = {_show(value)}")
            if full in meanings:
                lines.extend(
                    textwrap.wrap(meanings[full], width=114, initial_indent=" " * 6, subsequent_indent=" " * 6)
                )

    walk(cfg, "")
    lines += [
        "",
        "Hydra's own flags: --cfg job (print the composed config), --hydra-help, -m/--multirun. See docs/training.md.",
    ]
    return "\n".join(lines)


def _kind(full: str, value: Any) -> str:
    """A key's type as --help names it."""
    if value is None:
        kinds = NULLABLE.get(full)
        if kinds is None:
            return "any"
        kinds = tuple(t for t in kinds if not (t is int and float in kinds))  # an int is a float here
        return " or ".join({dict: "mapping"}.get(t, t.__name__) for t in kinds) + " or null"
    if OmegaConf.is_list(value):
        return "list"
    if OmegaConf.is_dict(value):
        return "mapping"
    return type(value).__name__
