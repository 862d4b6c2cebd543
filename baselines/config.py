"""The Hydra side of training: the ``level`` options taken from evaaa, a composed config checked key by key
(:func:`compose_checked`: types, bounds, what this machine and the algorithm accept), and the values the training
code derives from it (observation keys, env overrides, curriculum stages).  The command line around it (sweeps,
``--help``) is :mod:`evaaa_baselines.cli.training`'s; the config files' folder is :data:`~.paths.CONF_DIR`.

Every level and testbed evaaa lists is a ``level=<name>`` option without a file to keep in sync: :func:`register_levels`
stores one ``{name, overrides}`` node per name in Hydra's ConfigStore.  Files in ``conf/level/`` add options
beside them (``curriculum.yaml``; ``file.yaml``, a level from the user's own YAML file, ``level=file
level.file=path/to/my.yaml``) and would take precedence over a registered name.
"""

from __future__ import annotations

import contextlib
import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from hydra.core.config_store import ConfigStore
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from omegaconf import DictConfig, OmegaConf

import evaaa
from evaaa.sensors import SENSORS, resolve_modalities

from .cli import did_you_mean


def register_levels() -> None:
    """Make ``level=<name>`` available for every name in ``evaaa.LEVELS + evaaa.TESTBEDS``, and the ``level_stem``
    resolver that names a ``level=file`` run after its file."""
    if not OmegaConf.has_resolver("level_stem"):
        OmegaConf.register_new_resolver("level_stem", lambda path: Path(str(path)).stem)
    store = ConfigStore.instance()
    for name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
        store.store(group="level", name=name, node={"name": name, "overrides": {}})


def register_launchers() -> None:
    """Make evaaa's launcher plugins (hydra_plugins/evaaa_ray_launcher: ``hydra/launcher=ray_cluster``'s, and the
    submitit launchers of ``slurm`` and ``slurm_local`` whose requeued jobs resume) known to Hydra. Hydra finds
    launchers by walking the ``hydra_plugins`` namespace's folders, which misses the plugins of an editable install
    (their folder is reached through setuptools' import hook, not a path); registering them is Hydra's way for that
    (``Plugins.register``) and harmless where the walk found them."""
    from hydra.core.plugins import Plugins

    from hydra_plugins.evaaa_ray_launcher.ray_launcher import RayLauncher
    from hydra_plugins.evaaa_ray_launcher.submitit_launchers import LocalLauncher, SlurmLauncher

    for launcher in (RayLauncher, SlurmLauncher, LocalLauncher):
        Plugins.instance().register(launcher)


#: a step budget this large stands for none: the run is bounded by its time budget (``max_cpu_minutes``), as the
#: protocols' compute-matched runs are (every algorithm given the same CPU minutes, whatever env steps they buy)
COMPUTE_BOUND_STEPS = 1_000_000_000


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


def show(value: Any) -> str:
    if OmegaConf.is_config(value):
        value = OmegaConf.to_container(value)
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return "[" + ",".join(show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {show(v)}" for k, v in value.items()) + "}"
    return str(value)


def validate(cfg: DictConfig, defaults: DictConfig, path: str = "", typed: dict[str, str] | None = None) -> None:
    """Every value of a composed training config has the type of its default (from the same groups, without the
    command line's values) and lies within its :func:`limit_of`: ``total_steps=abc``, ``total_steps=-5`` or
    ``eval.sample=maybe`` is refused before any work, as is a key the defaults do not have (``+totl_steps=5`` would
    otherwise be ignored).  ``typed``: the text given for each key on the command line, which the message quotes
    (YAML reads ``1e3`` as 1000.0 and ``3_2`` as 32).  Raises :class:`ConfigError`."""
    typed = typed or {}

    def shown(full: str, value: Any) -> str:
        return typed.get(full, show(value))

    for key in cfg.keys() if OmegaConf.is_dict(cfg) else ():
        full = f"{path}{key}"
        if full.startswith(FREE_FORM):
            continue
        if key not in defaults.keys():  # ``in`` alone is false for a mandatory value (``???``) such as level.file
            here = [f"{path}{k}" for k in defaults.keys()]
            raise ConfigError(
                f"unknown key '{full}'{did_you_mean(full, here)}; keys here: {', '.join(here)} (see --help)"
            )
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
                f"{full}={shown(full, value)}: expected {_type_text(_allowed_types(default))} (default {show(default)})"
            )
        elif OmegaConf.is_dict(default):
            if not OmegaConf.is_dict(value):
                raise ConfigError(f"{full}={show(value)}: expected a mapping of {', '.join(default.keys())}")
            validate(value, default, f"{full}.", typed)
            continue
        elif OmegaConf.is_list(default):
            types = (list,)
        else:
            types = _allowed_types(default)
        plain = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
        if not _matches(plain, tuple(list if t is list else dict if t is dict else t for t in types)):
            read_as = ""
            if full in typed and typed[full] != show(value) and not isinstance(plain, (list, dict)):
                read_as = f"; YAML reads it as {show(value)}"  # 1e3 is a float to YAML, 3_2 the integer 32
            if str in types and not isinstance(plain, str):
                read_as += f": quote it to keep the text, e.g. '{full}=\"{shown(full, value)}\"'"
            elif int in types and float not in types and isinstance(plain, float) and plain.is_integer():
                read_as += f": write it as an integer, e.g. {full}={int(plain)} or {full}={int(plain):_}"
            raise ConfigError(
                f"{full}={shown(full, value)}: expected {_type_text(types)}"
                + ("" if default is None else f" (default {show(default)})")
                + read_as
            )
        bounds = limit_of(full)
        if bounds is not None and not isinstance(plain, (list, dict, bool, str)) and not bounds[0](plain):
            raise ConfigError(
                f"{full}={shown(full, value)}: expected {bounds[1]}"
                + ("" if default is None else f" (default {show(default)})")
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
                    f"(default {show(default)}), got {show(bad[0])}"
                )


def one_line(err: BaseException) -> str:
    return " ".join(str(err).split("\n")[0].split())


def group_choice(override: Override, groups: set[str]) -> bool:
    """Whether an override chooses a config group option (``algo=dqn``, ``hydra/launcher=basic``)."""
    key = override.key_or_group.split("@")[0]
    return "/" in key or key in groups


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
        raise ConfigError(f"{one_line(err)} (in {' '.join(overrides)}; lists are key=[a,b])") from None
    groups = set(loader.list_groups(""))
    chosen = [o.input_line for o in parsed if group_choice(o, groups)]
    for o in parsed:
        group = o.key_or_group.split("@")[0]
        if group in NOT_TRAINING[1:]:
            raise ConfigError(
                f"{o.input_line}: {group} is not a key of train.py (scripts/reproduce.py "
                f"{group}=<name> runs a protocol)"
            )
        if group_choice(o, groups) and o.value() is not None and not isinstance(o.value(), list):
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
            raise ConfigError(one_line(err)) from None
    defaults = _DEFAULTS[key]
    try:
        cfg = compose("config", overrides=list(overrides))
    except Exception as err:  # noqa: BLE001  (Hydra's composition errors have no common narrower base)
        cause = err.__cause__
        full_key = getattr(cause, "full_key", None)
        if full_key and "not in" in str(cause):
            parent = full_key.rpartition(".")[0]
            node = OmegaConf.select(defaults, parent) if parent else defaults
            here = [f"{parent + '.' if parent else ''}{k}" for k in (node.keys() if OmegaConf.is_dict(node) else ())]
            keys = ", ".join(here)
            if node is None:
                raise ConfigError(
                    f"unknown key '{full_key}': {parent} is null with these options; set it whole, "
                    f"e.g. {parent}={{{full_key.rpartition('.')[2]}: ...}}"
                ) from None
            if OmegaConf.is_dict(node) and not len(node):  # an empty mapping (env.overrides) takes new keys
                line = next((o.input_line for o in parsed if o.key_or_group.startswith(full_key)), full_key)
                raise ConfigError(f"'{full_key}' is not in {parent} yet: add it with ++{line.lstrip('+')}") from None
            raise ConfigError(
                f"unknown key '{full_key}'{did_you_mean(full_key, here)}; keys here: {keys} (see --help)"
            ) from None
        raise ConfigError(one_line(err)) from None
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
    from .devices import DeviceError, resolve_device

    try:
        device = resolve_device(cfg.device)
    except DeviceError as err:
        raise ConfigError(str(err)) from None
    backend = cfg.env.get("backend", "cpu")
    if backend not in evaaa.BACKENDS:
        raise ConfigError(f"env.backend={show(backend)}: expected one of {', '.join(evaaa.BACKENDS)}")
    if backend == "warp":
        from evaaa import mjwarp

        if not mjwarp.available():
            raise ConfigError(f"env.backend=warp: {mjwarp.INSTALL_HINT}")
    check_level_file(cfg)
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
                f"level.stages={text or show(cfg.level.stages)}: "
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


def check_level_file(cfg: DictConfig) -> None:
    """``level=file``: ``level.file`` is given and names a level file evaaa loads (read within its limits, never
    opened unless it is a regular file), whose stem can name the run's folder.  Checked before Hydra makes that folder,
    so a refused file ends in one line and leaves nothing behind.  Raises :class:`ConfigError`."""
    if "file" not in cfg.level.keys():  # ``in`` alone is false while level.file is ``???``
        return
    if OmegaConf.is_missing(cfg.level, "file"):
        raise ConfigError(
            "level=file needs level.file=<path of your level's .yaml file>, e.g. level.file=levels/my.yaml"
        )
    file = cfg.level.file
    if not isinstance(file, str) or not file:
        raise ConfigError(f"level.file={show(file)}: expected the path of a .yaml level file")
    level_file(file, "level.file")  # what stages() will do: it loads and checks the file


def level_file(file: str, key: str) -> str:
    """The name of the level in the user's file ``file``, named on a command line by ``key`` (``level.file`` of
    train.py, ``levels`` of evaluate.py, ``level`` of play.py), registered with :func:`evaaa.register_level` so that
    the name loads in this process.  A file that cannot be used is a :class:`ConfigError` of one line,
    ``<key>=<file>: <why>``, naming the file once, as the user typed it."""
    try:
        return evaaa.register_level(file)
    except evaaa.LevelError as err:
        first, *rest = (line.strip() for line in str(err).splitlines())  # a level's value errors: one line each
        message = first + (" " + "; ".join(rest) if rest else "")
        # evaaa names the file as it resolved it; said once, as the user typed it (a parent file keeps its own name)
        spellings = {file, str(Path(file))}
        with contextlib.suppress(OSError, RuntimeError):
            spellings.add(str(Path(file).resolve()))
        for spelling in sorted(spellings, key=len, reverse=True):
            message = message.replace(f"level file '{spelling}'", "the file").replace(
                f"invalid level '{spelling}'", "the level is invalid"
            )
        raise ConfigError(f"{key}={file}: {message}") from None


#: why ``algo=dreamer`` stops on a machine without a GPU, and what to type instead (docs/training.md, "DreamerV3")
CPU_DREAMER = (
    "algo=dreamer is DreamerV3 size S, a GPU size: no CUDA device here, and on a CPU one of its gradient "
    "steps takes 10-80 s (days for a level); algo=dreamer_xs is its CPU size, or add device=cpu to train "
    "size S on the CPU anyway"
)


_LAST: list[DictConfig] = []  # the last config compose_checked composed, and its defaults


def last_composed() -> tuple[DictConfig, DictConfig]:
    """The config :func:`compose_checked` composed last, and the defaults it was checked against."""
    cfg, defaults = _LAST
    return cfg, defaults
