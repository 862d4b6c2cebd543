"""The evaluation room: who plays, on which worlds, and what an evaluation writes.

Players: :class:`EvaluatedPolicy` (a reference agent — oracle, random, still — or a checkpoint, ``zoo:<name>``
included) and :class:`OwnPolicy` (a policy of your own: a TorchRL module, a callable on the observation TensorDict, a
callable on gymnasium's dict observation, or a Stable-Baselines3 model).  :func:`episode_records` plays one on a
level's test or validation worlds and returns its episodes as records (:mod:`evaaa.records`).

Writing: :func:`write_evaluation` plays every player on every level into ``out`` and writes ``episodes.csv``,
``summary.md`` and the figures (``scripts/evaluate.py`` is a thin command line over it); :func:`score` does the same
for a policy of your own beside the random and stand-still references:

>>> from evaaa_baselines.evaluation import score
>>> score(my_policy, levels=["1-1", "two-resource-food"], episodes=20, out="outputs/score-mine")  # doctest: +SKIP

Code runs only where it is named: ``scripts/evaluate.py policy=py:agent.py:policy`` imports ``agent.py`` because the
command line says so; no file an evaluation reads (checkpoints, level files, episode CSVs, protocols) can name code.
"""

from __future__ import annotations

import difflib
import hashlib
import importlib
import importlib.util
import os
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import Compose, EnvBase, Transform, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm import tqdm

import evaaa
from evaaa.agents import OracleAgent, RandomAgent, StillAgent
from evaaa.records import (
    DISK_ERRNOS,
    DiskError,
    EpisodeTracker,
    StepLog,
    append_rows,
    disk_error,
    new_log_path,
    read_rows,
)
from evaaa.sensors import resolve_modalities

from . import cli
from .cli import OWN_PREFIX, REFERENCE_AGENTS, is_own, own_source, own_spec_problem
from .policies import LoadedPolicy, load_policy
from .rollout import acting_mode
from .zoo import is_zoo

#: the policies of an evaluation that are not checkpoints (evaaa.agents): the privileged oracle, uniformly random
#: actions, and standing still
_REFERENCE = {"oracle": lambda seed: OracleAgent(), "random": RandomAgent, "still": lambda seed: StillAgent()}


class EvaluationError(ValueError):
    """A policy cannot be evaluated as asked (its checkpoint, its device, the level); the message says why."""


class EvaluatedPolicy:
    """One policy of an evaluation — ``oracle``, ``random``, ``still``, a checkpoint file or ``zoo:<name>`` — that
    builds the env of a level and picks actions for a batch of worlds.

    ``sample``: a checkpoint draws its actions from its distribution instead of taking the most likely one;
    ``epsilon``: the chance of a uniformly random action instead, at each step (drawn from a generator seeded with
    ``seed``, so runs repeat).  :attr:`name` and :attr:`acting` go into every episode row.
    """

    def __init__(
        self,
        spec: str,
        seed: int,
        modalities: list[str] | None = None,
        epsilon: float = 0.0,
        sample: bool = False,
        device: str = "cpu",
    ):
        self.spec = spec
        self.seed = seed
        self.epsilon = epsilon
        self.sample = sample
        self.rng = torch.Generator().manual_seed(seed)  # epsilon's draws: the same for every run of the command
        self.loaded: LoadedPolicy | None = None
        if spec not in REFERENCE_AGENTS:
            path = Path(spec)
            if not (is_zoo(spec) or path.is_file()):
                raise EvaluationError(
                    f"policy {spec!r} is neither {', '.join(REFERENCE_AGENTS)}, zoo:NAME, a checkpoint file nor "
                    f"{OWN_PREFIX}MODULE:NAME (a policy of your own)"
                )
            try:
                self.loaded = load_policy(spec if is_zoo(spec) else path, modalities=modalities, device=device)
            except ValueError as err:  # e.g. modalities= names keys the checkpoint was not trained on
                raise EvaluationError(f"policy={spec}: {err}") from None
        # a checkpoint is named by its path: reports look the run's configuration up from it; a zoo network, which
        # has no run here, by its zoo name
        self.name = spec if self.loaded is None or is_zoo(spec) else str(path)
        # how it acts, recorded with every episode so that evaluations made in different ways stay apart
        self.acting = acting_mode(None if self.loaded is None else self.loaded.algo, sample, epsilon)

    def make_env(self, level: str, num_envs: int, seed: int, worlds: str = "test") -> EnvBase:
        """The ``worlds`` (``test`` or ``validation``: :mod:`evaaa.worlds`) of ``level`` this policy acts in (a
        reference agent reads the simulator; the env gives it the EVs only)."""
        if worlds not in ("test", "validation"):  # published numbers never come from a training world
            raise EvaluationError(f"worlds must be test or validation, got {worlds!r}")
        if self.loaded is not None:
            try:
                return self.loaded.make_env(level, num_envs=num_envs, seed=seed, overrides={}, worlds=worlds)
            except ValueError as err:
                raise EvaluationError(str(err)) from None
        self.agent = _REFERENCE[self.spec](seed)
        return evaaa.make_env(
            level, num_envs=num_envs, seed=seed, modalities=["interoception"], info=True, worlds=worlds
        )

    def act(self, env: EnvBase, td: TensorDictBase) -> torch.Tensor:
        if self.loaded is not None:
            action = self.loaded(td, deterministic=not self.sample)["action"]
            if self.epsilon > 0:  # epsilon-greedy evaluation: a uniformly random action instead, now and then
                explore = torch.rand(action.shape, generator=self.rng) < self.epsilon
                other = torch.randint(0, len(evaaa.ACTION_NAMES), action.shape, generator=self.rng)
                action = torch.where(explore, other, action)
            return action
        sim = env.sim if hasattr(env, "sim") else env.base_env.sim
        return torch.from_numpy(self.agent.act(sim))


def episode_records(
    policy: EvaluatedPolicy,
    level: str,
    *,
    episodes: int,
    num_envs: int,
    seed: int,
    worlds: str = "test",
    step_log: StepLog | None = None,
    on_episode: Callable[[], None] | None = None,
) -> list[dict]:
    """``episodes`` episodes of ``policy`` on ``level`` in ``num_envs`` of the ``worlds`` (``test`` or ``validation``)
    of ``seed``, as episode rows (:class:`evaaa.records.EpisodeTracker`, with a ``worlds`` column; ``episode``
    numbered from 0 in the order they ended).  Each world runs its share of the episodes; ``step_log`` gets every
    decision; ``on_episode`` is called per counted episode."""
    env = policy.make_env(level, num_envs, seed, worlds)
    torch.manual_seed(seed)  # sampled actions (sample=true) repeat from run to run
    n = num_envs
    quota = np.full(n, episodes // n) + (np.arange(n) < episodes % n)  # episodes each world runs
    tracker = EpisodeTracker(n, level, policy.name, seed=seed, acting=policy.acting, worlds=worlds)
    rows: list[dict] = []
    td = env.reset()
    if step_log is not None:
        step_log.start(level, td["info"], seed=seed, policy=policy.name, acting=policy.acting)
    done_count = np.zeros(n, dtype=int)
    while (done_count < quota).any():
        td["action"] = policy.act(env, td).reshape(env.action_spec.shape)
        step, td = env.step_and_maybe_reset(td)
        nxt = step["next"]
        info = {k: v.reshape(n, -1) for k, v in nxt["info"].items()}
        done = nxt["done"].reshape(n).numpy()
        finished = tracker.update(nxt["reward"].reshape(n).numpy(), info, done, actions=step["action"])
        if step_log is not None:
            step_log.update(step["action"], nxt["reward"], info, done, td["info"])
        for w, row in zip(np.flatnonzero(done), finished):  # rows come in the order of the finished worlds
            if done_count[w] < quota[w]:  # a world's episodes beyond its quota are not counted
                rows.append(row)
                if on_episode is not None:
                    on_episode()
            done_count[w] += 1
    env.close()
    for i, row in enumerate(rows):
        row["episode"] = i
    return rows


# ------------------------------------------------------------------------------------------------ your own policy
#: what a policy of your own may be, in words (errors, ``--help``)
OWN_FORMS = (
    "a TorchRL module (TensorDictModuleBase), a Stable-Baselines3 model, a callable on the observation TensorDict, "
    "or a callable on gymnasium's dict observation marked with @gym_policy"
)
_GYM_MARK = "__evaaa_gym_policy__"


def gym_policy(fn: Callable[[dict[str, np.ndarray]], Any]) -> Callable[[dict[str, np.ndarray]], Any]:
    """Mark ``fn`` as a policy on gymnasium's observation: called once per world with the dict of numpy arrays that
    ``gymnasium.make("evaaa/<level>-v0")`` returns (one world, no batch axis), it returns that world's action (an
    integer 0..4).  Unmarked callables are called on the TensorDict of every world at once."""
    setattr(fn, _GYM_MARK, True)
    return fn


def load_own(spec: str) -> Any:
    """The object ``py:<module>:<name>`` or ``py:<file.py>:<name>`` names: the module is imported (a file is run as a
    module, its folder on the import path while it loads) — the one place an evaluation runs code it is given, and
    only because a command line named it.  Raises :class:`EvaluationError` in one line for a malformed name, a file
    that is not there, an import that fails (the error it raised) or a missing attribute."""
    problem = own_spec_problem(spec)
    if problem is not None:
        raise EvaluationError(problem)
    source, attr, is_file = own_source(spec)
    try:
        if is_file:
            path = Path(source).resolve()
            name = "evaaa_own_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
            module_spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(module_spec)
            sys.modules[name] = module  # dataclasses and pickles look their module up there
            sys.path.insert(0, str(path.parent))  # its own imports of files beside it
            try:
                module_spec.loader.exec_module(module)
            finally:
                sys.path.remove(str(path.parent))
        else:
            module = importlib.import_module(source)
    except (Exception, SystemExit) as err:  # noqa: BLE001 - the user's own code: its error, in one line
        raise EvaluationError(
            f"policy={spec}: importing {source} raised {type(err).__name__}: {' '.join(str(err).split())[:200]}"
        ) from None
    found: Any = module
    for part in attr.split("."):
        if not hasattr(found, part):
            names = [n for n in dir(found) if not n.startswith("_")]
            close = difflib.get_close_matches(part, names, n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise EvaluationError(f"policy={spec}: {source} has no '{part}'{hint}")
        found = getattr(found, part)
    return found


def _is_sb3(policy: Any) -> bool:
    """A Stable-Baselines3 model or policy (anything with SB3's ``predict(obs, deterministic=)`` and a gymnasium
    ``observation_space``)."""
    return callable(getattr(policy, "predict", None)) and hasattr(policy, "observation_space")


class OwnPolicy:
    """A policy of your own, played as the reference agents and checkpoints are (:func:`episode_records`).

    ``policy`` is one of:

    * a TorchRL module (``TensorDictModuleBase``): called on the worlds' TensorDict, it writes ``"action"``; it acts
      deterministically (``ExplorationType.DETERMINISTIC``) unless ``sample=True``;
    * a Stable-Baselines3 model (``PPO.load(...)``) or policy: ``predict(obs, deterministic=not sample)`` per world on
      gymnasium's dict observation, the one it was trained on through ``gymnasium.make("evaaa/<level>-v0")``;
    * a callable marked with :func:`gym_policy`: called per world on gymnasium's dict observation;
    * any other callable: called on the worlds' TensorDict (batch ``[num_envs]``), returning the actions (a tensor,
      an array or a TensorDict holding ``"action"``).

    Actions are integers 0..4 (``evaaa.ACTION_NAMES``).  The policy sees the observation keys of ``modalities``
    (default: every sense; an SB3 model's own keys), never the diagnostics under ``"info"``.  ``transforms``: a
    function returning fresh TorchRL transforms (one or a list) for every env made, e.g. the frame stack or
    recurrent-state primer the policy was trained with.
    """

    def __init__(
        self,
        policy: Any,
        *,
        name: str | None = None,
        sample: bool = False,
        modalities: Iterable[str] | None = None,
        transforms: Callable[[], Transform | Sequence[Transform]] | None = None,
    ):
        if not (callable(policy) or _is_sb3(policy)):
            raise EvaluationError(f"policy {policy!r} is not a policy: expected {OWN_FORMS}")
        self.policy, self.sample, self.transforms = policy, sample, transforms
        if isinstance(policy, TensorDictModuleBase):
            self.kind = "torchrl"
        elif _is_sb3(policy):
            self.kind = "sb3"
        elif getattr(policy, _GYM_MARK, False):
            self.kind = "gym"
        else:
            self.kind = "tensordict"
        self.name = name or getattr(policy, "__name__", None) or type(policy).__name__
        # how it acts, as every row records it: a module's or model's mode or samples; a plain callable's is its own
        self.acting = ("sample" if sample else "mode") if self.kind in ("torchrl", "sb3") else ""
        try:
            keys = resolve_modalities(modalities)
        except ValueError as err:
            raise EvaluationError(f"modalities: {err}") from None
        if self.kind == "sb3":
            trained = tuple(getattr(policy.observation_space, "spaces", {}) or ())
            unknown = sorted(set(trained) - set(evaaa.MODALITIES))
            if not trained or unknown:
                raise EvaluationError(
                    f"policy {self.name}: its observation space is not evaaa's dict observation "
                    f"(keys {list(trained) or 'none'}; evaaa's: {list(evaaa.MODALITIES)})"
                )
            if modalities is not None and set(keys) != set(trained):
                raise EvaluationError(
                    f"policy {self.name} was trained on observation keys {sorted(trained)}, not {sorted(keys)}"
                )
            keys = resolve_modalities(trained)
        self.modalities = keys

    def make_env(self, level: str, num_envs: int, seed: int, worlds: str = "test") -> EnvBase:
        """The ``worlds`` of ``level`` with this policy's observation keys (and its transforms)."""
        if worlds not in ("test", "validation"):
            raise EvaluationError(f"worlds must be test or validation, got {worlds!r}")
        env = evaaa.make_env(level, num_envs=num_envs, seed=seed, modalities=self.modalities, info=True, worlds=worlds)
        if self.transforms is None:
            return env
        made = self.transforms()
        return TransformedEnv(env, Compose(*([made] if isinstance(made, Transform) else made)))

    def act(self, env: EnvBase, td: TensorDictBase) -> torch.Tensor:
        n = td.batch_size.numel()
        seen = td.exclude("info")  # diagnostics are never a policy's input
        with torch.no_grad():
            if self.kind == "torchrl":
                mode = ExplorationType.RANDOM if self.sample else ExplorationType.DETERMINISTIC
                with set_exploration_type(mode):
                    out = self.policy(seen)
                td.update(out.exclude("action"))  # a recurrent module's state rides on to the next step
                action = out.get("action", None)
            elif self.kind == "tensordict":
                out = self.policy(seen)
                action = out.get("action", None) if isinstance(out, TensorDictBase) else out
            else:
                action = [self._one(seen, w) for w in range(n)]
        return self._actions(action, n)

    def _one(self, seen: TensorDictBase, world: int) -> Any:
        """One world's action from a gymnasium-side policy: its observation as gymnasium gives it."""
        obs = {key: seen[key][world].cpu().numpy() for key in self.modalities}
        if self.kind == "sb3":
            action, _ = self.policy.predict(obs, deterministic=not self.sample)
            return action
        return self.policy(obs)

    def _actions(self, action: Any, n: int) -> torch.Tensor:
        """``action`` as ``n`` int64 actions, or :class:`EvaluationError` saying what came back instead."""
        if action is None:
            raise EvaluationError(f"policy {self.name} wrote no 'action' (expected {n} actions, integers 0..4)")
        try:
            if isinstance(action, torch.Tensor):
                values = action.detach().cpu().numpy()
            elif isinstance(action, list):  # one per world, from a gymnasium-side policy
                values = np.concatenate([np.asarray(a).reshape(-1) for a in action])
            else:
                values = np.asarray(action)
            values = values.reshape(-1)
        except (TypeError, ValueError) as err:
            raise EvaluationError(f"policy {self.name} returned {type(action).__name__}, not actions ({err})") from None
        integral = values.dtype.kind in "iu" or (values.dtype.kind == "f" and bool(np.all(np.mod(values, 1) == 0)))
        in_range = values.size > 0 and values.min() >= 0 and values.max() < len(evaaa.ACTION_NAMES)
        if values.size != n or not integral or not in_range:
            shown = np.array2string(values[:8], separator=",")
            raise EvaluationError(
                f"policy {self.name} returned {values.size} values {shown} for {n} worlds; expected one action per "
                f"world, an integer 0..{len(evaaa.ACTION_NAMES) - 1} ({', '.join(evaaa.ACTION_NAMES)})"
            )
        return torch.as_tensor(values.astype(np.int64))


def player(spec: Any, seed: int, **options: Any) -> EvaluatedPolicy | OwnPolicy:
    """The player a policy argument names: ``oracle``, ``random``, ``still``, a checkpoint file or ``zoo:<name>``
    (:class:`EvaluatedPolicy`; ``options`` modalities, epsilon, sample, device), ``py:...`` (its object, as
    :class:`OwnPolicy` named by the spec; ``options`` sample, modalities) or an object (:class:`OwnPolicy`)."""
    if isinstance(spec, OwnPolicy):
        return spec
    if is_own(spec):
        own = {k: options[k] for k in ("sample", "modalities") if k in options}
        return OwnPolicy(load_own(spec), name=spec, **own)
    if isinstance(spec, (str, Path)):
        return EvaluatedPolicy(str(spec), seed, **options)
    own = {k: options[k] for k in ("sample", "modalities") if k in options}
    return OwnPolicy(spec, **own)


# ------------------------------------------------------------------------------------------------ levels
#: the level groups ``levels`` takes besides level and testbed names
LEVEL_GROUPS = {"testbeds": evaaa.TESTBEDS, "training": evaaa.LEVELS, "all": evaaa.LEVELS + evaaa.TESTBEDS}


def expand_levels(names: Iterable[str], given: str | None = None) -> tuple[list[str], dict[str, Path]]:
    """The levels ``names`` stand for, in order (groups expanded, repeats dropped), and the file each level of your
    own was read from (registered, so that its name loads).  A name that is none of them raises
    :class:`EvaluationError` in one line naming the closest names; ``given``: the text typed, for the message."""
    levels: list[str] = []
    files: dict[str, Path] = {}
    names = list(names)
    given = given if given is not None else f"[{','.join(map(str, names))}]"
    for name in map(str, names):
        if name in LEVEL_GROUPS:
            found = tuple(LEVEL_GROUPS[name])
        elif name in (*evaaa.LEVELS, *evaaa.TESTBEDS):
            found = (name,)
        elif name.endswith((".yaml", ".yml")):
            from .config import ConfigError, level_file  # Hydra's: only where a level file is named

            try:
                found = (level_file(name, "levels"),)
            except ConfigError as err:
                raise EvaluationError(str(err)) from None
            files[found[0]] = Path(name).resolve()
        else:
            allowed = [*evaaa.LEVELS, *evaaa.TESTBEDS, *LEVEL_GROUPS]
            raise EvaluationError(
                f"levels={given}: '{name}' is not allowed{cli.did_you_mean(name, allowed)}; allowed: "
                f"{', '.join(allowed)}, or {cli.OWN_LEVEL}"
            )
        levels += [level for level in found if level not in levels]
    return levels, files


# ------------------------------------------------------------------------------------------------ writing
#: what an evaluation writes to ``out``: any of them there means ``out`` already holds one
OUTPUTS = ("episodes.csv", "summary.md", "success.png", "survival.png", "outcomes.png")


def earlier_evaluation(out: str | Path) -> bool:
    """Whether ``out`` holds an evaluation stopped after its ``episodes.csv`` and before its ``summary.md`` (written
    last), which the same command completes.  Raises :class:`EvaluationError` when ``out`` holds a complete or other
    evaluation: appending would pool two evaluations (n doubles, the standard error shrinks), replacing would lose
    one."""
    out = Path(out)
    earlier = [name for name in OUTPUTS if (out / name).exists()]
    completing = bool(earlier) and "episodes.csv" in earlier and "summary.md" not in earlier
    if earlier and not completing:
        raise EvaluationError(
            f"{out} already holds an evaluation ({', '.join(earlier)}); nothing was changed: choose another out=, "
            "or move those files away first"
        )
    return completing


def _writable(out: Path) -> None:
    """Fail now, not after the episodes, where ``out`` cannot take files: a real write of 64 KiB made durable
    (root passes permission checks yet cannot write a read-only mount, and a full disk still creates empty files)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".write-test-") as probe:
            probe.write(bytes(64 * 1024))
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        raise DiskError(out, exc) from None


def _atomic(path: Path, write: Callable[[Path], Any]) -> Path:
    """``write(tmp)`` then rename ``tmp`` to ``path``: a full disk leaves no half-written file under its name."""
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        error = disk_error(path, exc) if isinstance(exc, OSError) else None
        if error is None:
            raise
        raise error from None
    return path


@dataclass(frozen=True)
class Evaluation:
    """What an evaluation wrote: ``out``, its ``files`` (``episodes.csv``, ``summary.md``, figures) and its
    summary ``table`` (Markdown, as ``summary.md`` holds it)."""

    out: Path
    files: list[Path]
    table: str

    @property
    def episodes(self) -> Path:
        return self.out / "episodes.csv"


def write_evaluation(
    players: Sequence[EvaluatedPolicy | OwnPolicy],
    levels: Sequence[str],
    out: str | Path,
    *,
    episodes: int,
    num_envs: int,
    seed: int,
    worlds: str = "test",
    include: Sequence[str | Path] = (),
    step_log: bool = False,
    level_files: dict[str, Path] | None = None,
    sample: bool = False,
    epsilon: float = 0.0,
    notes: Sequence[str] = (),
    completing: bool | None = None,
    say: Callable[[str], None] = print,
) -> Evaluation:
    """Play ``episodes`` episodes of every player on every level (``worlds`` of ``seed``) and write them to ``out``:
    ``episodes.csv`` (put in place once every episode is done), then the figures, then ``summary.md`` last (the
    mark of a complete evaluation).  ``out`` must not hold an earlier evaluation; one stopped between its
    ``episodes.csv`` and its ``summary.md`` is completed (``completing``: :func:`earlier_evaluation`'s answer, when
    the caller asked already).  ``include``: other episode CSVs for the summary (human play); ``notes``: lines for
    the summary's head; ``sample`` / ``epsilon``: how checkpoints acted, said in it.  Every problem raises
    :class:`EvaluationError` in one line; a folder this call made stays only if it holds something."""
    out = Path(out)
    if completing is None:
        completing = earlier_evaluation(out)
    made = not out.exists()
    try:
        _writable(out)
    except DiskError as err:
        if made and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise EvaluationError(f"{err}; nothing was written, no episode was played") from None
    if completing:
        _check_episodes(out / "episodes.csv", players, levels, episodes, seed, worlds)
        say(f"{out / 'episodes.csv'} holds every episode of this evaluation: writing its summary and figures")
    else:
        try:
            _play(
                players,
                levels,
                out,
                episodes=episodes,
                num_envs=num_envs,
                seed=seed,
                worlds=worlds,
                step_log=step_log,
                say=say,
            )
        except DiskError as err:
            raise EvaluationError(
                f"{err}; no episodes.csv was written (run the command again once the disk takes writes)"
            ) from None
        except EvaluationError:  # an episode refused: a folder this call made stays only if used
            if made and out.is_dir() and not any(out.iterdir()):
                out.rmdir()
            raise
    try:
        files, table = _summarize(
            out, levels, episodes, seed, worlds, include, level_files or {}, sample, epsilon, notes
        )
    except OSError as err:
        if err.errno not in DISK_ERRNOS:
            raise
        raise EvaluationError(
            f"{disk_error(err.filename or out, err)}; episodes.csv is complete: the same command writes the summary "
            "and figures once the disk takes writes"
        ) from None
    return Evaluation(out, files, table)


def _check_episodes(
    path: Path, players: Sequence[Any], levels: Sequence[str], episodes: int, seed: int, worlds: str
) -> None:
    """Refuse an ``episodes.csv`` that is not every episode this evaluation asks for."""
    rows = read_rows(path)
    counts = Counter((r["policy"], r["acting"], r["level"], r["seed"], r.get("worlds")) for r in rows)
    wanted = {(p.name, p.acting, level, str(seed), worlds): episodes for p in players for level in levels}
    if counts != wanted:
        missing = [f"{key[0]} on {key[2]}" for key, n in wanted.items() if counts.get(key) != n]
        raise EvaluationError(
            f"{path} holds other episodes than this command's ({len(rows)} rows; not as asked: "
            f"{', '.join(missing[:3]) or 'episodes of other policies or levels'}); nothing was changed: choose "
            "another out=, or repeat the command that made it"
        )


def _play(
    players: Sequence[Any],
    levels: Sequence[str],
    out: Path,
    *,
    episodes: int,
    num_envs: int,
    seed: int,
    worlds: str,
    step_log: bool,
    say: Callable[[str], None],
) -> None:
    total = len(players) * len(levels) * episodes
    # episodes go to a hidden file until the last one is done: an interrupted evaluation leaves no episodes.csv
    partial = out / ".episodes.csv.partial"
    partial.unlink(missing_ok=True)  # an earlier interrupted evaluation's
    log = StepLog(new_log_path(out)) if step_log else None
    try:
        with tqdm(total=total, desc="episodes", unit="ep", dynamic_ncols=True) as bar:
            for policy in players:
                for level in levels:
                    bar.set_postfix_str(f"{policy.name} on {level}")
                    rows = episode_records(
                        policy,
                        level,
                        episodes=episodes,
                        num_envs=num_envs,
                        seed=seed,
                        worlds=worlds,
                        step_log=log,
                        on_episode=lambda: bar.update(1),
                    )
                    append_rows(partial, rows)
        os.replace(partial, out / "episodes.csv")
    except DiskError:
        partial.unlink(missing_ok=True)
        raise
    finally:
        if log is not None:
            log.close()
    if log is not None:
        say(f"step log: {log.path}")


def _bars(summary) -> str:
    """How many episodes each bar of a figure stands for, for its title."""
    counts = sorted(set(summary["episodes"]))
    return f"{counts[0]} episodes per bar" if len(counts) == 1 else f"{counts[0]}–{counts[-1]} episodes per bar"


def _summarize(
    out: Path,
    levels: Sequence[str],
    episodes: int,
    seed: int,
    worlds: str,
    include: Sequence[str | Path],
    level_files: dict[str, Path],
    sample: bool,
    epsilon: float,
    notes: Sequence[str],
) -> tuple[list[Path], str]:
    """summary.md and the figures from ``out/episodes.csv``; summary.md last, so that it marks a complete
    evaluation."""
    from . import reports  # pandas, matplotlib and scipy load once there are episodes to summarise

    rows = reports.read_episodes([out / "episodes.csv", *include])
    rows = rows[rows["level"].isin(levels)]
    summary = reports.summarize(rows)
    table = reports.markdown_table(summary)
    written = [out / "episodes.csv"]
    # a level of your own is drawn with the testbeds where it has a success rule, else with the training levels
    own, judged = ~summary["level"].isin((*evaaa.LEVELS, *evaaa.TESTBEDS)), summary["success_rate"].notna()
    tests = summary[summary["level"].isin(evaaa.TESTBEDS) | (own & judged)]
    if len(tests):
        title = f"Success per testbed ({_bars(tests)})"
        written.append(
            _atomic(out / "success.png", lambda p: reports.plot_summary(tests, p, success=True, title=title))
        )
    training = summary[summary["level"].isin(evaaa.LEVELS) | (own & ~judged)]
    if len(training):
        title = f"Survival per training level ({_bars(training)})"
        written.append(
            _atomic(out / "survival.png", lambda p: reports.plot_summary(training, p, success=False, title=title))
        )
    written.append(_atomic(out / "outcomes.png", lambda p: reports.plot_outcomes(rows, p)))
    text = (
        f"# Evaluation ({episodes} episodes per level and policy, {worlds} worlds of seed {seed}"
        + ("; checkpoints sample their actions (DQN's act greedily: it has no distribution)" if sample else "")
        + (f"; checkpoints act epsilon-greedily, epsilon {epsilon:g}" if epsilon else "")
        + ")\n\n"
        + "".join(f"{note}\n\n" for note in notes)
        + "".join(f"Level {name}: the file {level_files[name]}.\n\n" for name in levels if name in level_files)
        + reports.SUMMARY_NOTE
        + "\n\n"
        + table
        + "\n"
    )
    written.insert(1, _atomic(out / "summary.md", lambda p: p.write_text(text)))
    return written, table


# ------------------------------------------------------------------------------------------------ scoring
#: the references :func:`score` plays beside a policy of your own, on the same worlds
SCORE_REFERENCES = ("random", "still")


def score(
    policy: Any,
    levels: Sequence[str] = ("testbeds",),
    *,
    episodes: int = 20,
    out: str | Path = "outputs/score",
    name: str | None = None,
    worlds: str = "test",
    seed: int = 0,
    num_envs: int = 4,
    references: Sequence[str] = SCORE_REFERENCES,
    modalities: Iterable[str] | None = None,
    transforms: Callable[[], Transform | Sequence[Transform]] | None = None,
    sample: bool = False,
) -> Evaluation:
    """Score a policy of your own on levels and testbeds, beside the random and stand-still references on the same
    worlds, as ``scripts/evaluate.py`` scores the baselines: ``episodes.csv``, ``summary.md`` and figures in ``out``.

    Args:
        policy: a TorchRL module, a Stable-Baselines3 model, a callable on the observation TensorDict, a callable on
            gymnasium's dict observation marked with :func:`gym_policy` (:class:`OwnPolicy` says how each is
            called), an :class:`OwnPolicy`, or what ``evaluate.py policy=`` takes (a checkpoint, ``zoo:<name>``,
            ``py:<module>:<name>``).
        levels: level and testbed names, the groups ``testbeds``, ``training``, ``all``, or paths of level files.
        episodes: episodes per level and policy, on the ``worlds`` (``test``: every published number;
            ``validation``: for choosing settings) of ``seed``, ``num_envs`` at a time.
        out: the folder written; it must not hold an earlier evaluation.
        name: the policy's name in the rows, the table and the figures (default: its ``__name__`` or class).
        references: reference agents played beside it (``oracle``, ``random``, ``still``).
        modalities, transforms, sample: what the policy sees and how it acts (:class:`OwnPolicy`).

    Returns the :class:`Evaluation` (files written, summary table).  Every problem raises :class:`EvaluationError`
    in one line, before anything is written where it can be found then.
    """
    if not isinstance(episodes, int) or episodes < 1 or not isinstance(num_envs, int) or num_envs < 1:
        raise EvaluationError(f"episodes={episodes}, num_envs={num_envs}: expected positive integers")
    if worlds not in ("test", "validation"):
        raise EvaluationError(f"worlds={worlds!r}: expected test or validation (never training worlds)")
    bad = [r for r in references if r not in REFERENCE_AGENTS]
    if bad:
        raise EvaluationError(f"references: {bad[0]!r} is not allowed; allowed: {', '.join(REFERENCE_AGENTS)}")
    chosen, files = expand_levels([levels] if isinstance(levels, str) else levels)
    out = Path(out)
    completing = earlier_evaluation(out)
    if isinstance(policy, OwnPolicy):
        own = policy
    elif isinstance(policy, (str, Path)):
        own = player(str(policy), seed, sample=sample, modalities=modalities)
    else:
        own = OwnPolicy(policy, name=name, sample=sample, modalities=modalities, transforms=transforms)
    if name is not None and isinstance(own, OwnPolicy):
        own.name = name
    if own.name in references:
        raise EvaluationError(f"name={own.name!r}: a reference agent's name; name your policy otherwise")
    players = [own, *(EvaluatedPolicy(r, seed) for r in dict.fromkeys(references))]
    return write_evaluation(
        players,
        chosen,
        out,
        episodes=episodes,
        num_envs=num_envs,
        seed=seed,
        worlds=worlds,
        level_files=files,
        completing=completing,
        notes=[own_note(own, references)] if isinstance(own, OwnPolicy) else [],
    )


def own_note(own: OwnPolicy, references: Sequence[str]) -> str:
    """The line of ``summary.md`` that says what a policy of your own is and what played beside it."""
    forms = {
        "torchrl": "a TorchRL module",
        "sb3": "a Stable-Baselines3 model",
        "gym": "a callable on gymnasium's observation",
        "tensordict": "a callable on the observation TensorDict",
    }
    beside = f"; {' and '.join(references)} played the same worlds" if references else ""
    acting = {"mode": ", its most likely actions", "sample": ", its actions sampled"}.get(own.acting, "")
    return f"Policy {own.name}: {forms[own.kind]}{acting}, seeing {', '.join(own.modalities)}{beside}."
