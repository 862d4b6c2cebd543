"""Offline probes of a finished DreamerV3 run, read from its last checkpoint and memory-mapped replay; nothing in
training calls them (``scripts/probe_dreamer.py`` and ``scripts/fit_world_model.py`` do): how well the latent holds
the EVs (:func:`ev_decoding_errors`, linear read-outs), what imagination says each action is worth
(:func:`imagined_action_values`), how fast a fresh world model learns what eating does from the stored replay
(:func:`fit_world_model`), and whether the observations say when eating will work (:func:`eat_success_readout`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torch.nn import functional as F

from evaaa import ACTION_NAMES

from ..checkpoint import CHECKPOINT, load_checkpoint
from ..nets import symlog
from .losses import WorldModelLoss
from .model import LATENT, NUM_ACTIONS, DreamerModel, make_model, one_hot_action, world_model


def _run_replay(run_dir: str | Path) -> tuple[dict, TensorDictBase, int, int]:
    """A DreamerV3 run's last checkpoint and the rows its memory-mapped replay holds ``[rows, worlds]``, with the
    number of worlds and of rows; refused for another algorithm, a run without interoception or a replay kept in
    memory."""
    state = load_checkpoint(Path(run_dir) / CHECKPOINT)
    if state.get("algo") not in ("dreamer", "dreamer_xs") or "interoception" not in state["obs_keys"]:
        raise ValueError(f"{run_dir}: not a DreamerV3 run that observes interoception")
    replay = state["components"]["replay"]
    if "on_disk" not in replay:
        raise ValueError(f"{run_dir}: its replay buffer was kept in memory (algo.buffer_on_disk=false), not on disk")
    num_envs = int(state["num_envs"])
    rows = replay["length"] // num_envs
    return state, TensorDict.load_memmap(replay["on_disk"])[:rows], num_envs, rows


def _probe_replay(
    run_dir: str | Path, sequences: int, model_file: str | Path | None = None
) -> tuple[dict, DictConfig, DreamerModel, TensorDictBase, int]:
    """A DreamerV3 run's last checkpoint (its state, config and model; with ``model_file``, the networks of that file
    instead, e.g. ``model-best-0-1-1.pt``), ``sequences`` replayed sequences of 32 steps from its memory-mapped
    replay, around the last eating steps stored (spread over the replay where there are too few), with the zero
    initial latent the world model starts from, and the env steps the networks had trained for: what the probes
    read."""
    state, data, num_envs, rows = _run_replay(run_dir)
    networks, steps = state, int(state["counters"]["steps"])
    if model_file is not None:
        networks = load_checkpoint(Path(model_file))
        if networks.get("algo") != state["algo"] or networks.get("obs_shapes") != state["obs_shapes"]:
            raise ValueError(
                f"model={model_file}: not the networks of this run's algorithm and observations "
                f"({state['algo']}, {sorted(state['obs_shapes'])})"
            )
        steps = int(networks.get("env_steps") or networks.get("counters", {}).get("steps", 0))
    cfg = OmegaConf.create(networks["config"])
    model = make_model(cfg.algo, {k: tuple(v) for k, v in state["obs_shapes"].items()})
    model.load_state_dict(networks["model"])
    model.eval()
    length = min(32, rows)
    eaten = data["next", "consumed"].reshape(rows, num_envs).nonzero()
    spread = torch.stack([torch.arange(sequences) * rows // sequences, torch.arange(sequences) % num_envs], dim=1)
    anchors = torch.cat([eaten[-sequences:], spread])[:sequences]  # too few eating steps: others, spread out
    start = (anchors[:, 0] - length // 2).clamp(0, rows - length)
    batch = data[start[:, None] + torch.arange(length), anchors[:, 1:2]].clone()
    batch["state"] = torch.zeros(*batch.shape, model.state_dim)
    batch["belief"] = torch.zeros(*batch.shape, model.belief_dim)
    return state, cfg, model, batch, steps


def ev_decoding_errors(
    run_dir: str | Path, sequences: int = 64, model_file: str | Path | None = None
) -> dict[str, Any]:
    """How well a DreamerV3 run's world model knows the EVs: the mean absolute error, in raw units, of the
    interoception decoded from the posterior, on the eating steps and on the other steps of ``sequences`` replayed
    sequences of 32 steps around the last eating steps stored (spread over the replay where there are too few),
    with the run's last checkpoint and its memory-mapped replay.  The reward is computed from the EVs: a latent
    that does not hold them cannot predict it."""
    from evaaa import EV_NAMES

    _, _, model, batch, steps = _probe_replay(run_dir, sequences, model_file)
    with torch.no_grad():
        out = world_model(model)(batch)
    error = (out["next", "reco_interoception"] - out["next", "interoception"]).abs()
    at = out["next", "consumed"].reshape(batch.shape)
    result: dict[str, Any] = {"env_steps": steps, "sequences": len(batch), "eating_steps": int(at.sum())}
    for name, mask in (("eating", at), ("other", ~at)):
        per_ev = error[mask].mean(0) if mask.any() else torch.full((len(EV_NAMES),), float("nan"))
        result[name] = dict(zip(EV_NAMES, per_ev.tolist()))
    # where the EVs are lost: a linear read-out of them from each stage, fitted on half of the sequences and
    # measured on the other half as the share of their variance it explains (the decoder is one read-out; these say
    # whether the information is there at all)
    target = out["next", "interoception"].float().reshape(-1, len(EV_NAMES))
    fit = (torch.arange(len(batch)) % 2 == 0)[:, None].expand(batch.shape).reshape(-1)
    nxt = out["next"]
    # "nothing": a constant feature (the fitted rows' mean, about 0 by construction): the check of the read-out
    sources = {
        "nothing": torch.zeros(*batch.shape, 1),
        "embedding": nxt["encoded_latents"],
        "stochastic latent": nxt["state"],
        "deterministic state": nxt["belief"],
        "latent (both)": torch.cat([nxt["state"], nxt["belief"]], -1),
    }
    result["linear_probe"] = (
        {
            name: dict(zip(EV_NAMES, linear_probe_r2(x.float().reshape(len(target), -1), target, fit).tolist()))
            for name, x in sources.items()
        }
        if bool(fit.any()) and bool((~fit).any())
        else {}
    )
    return result


def fit_world_model(
    run_dir: str | Path,
    updates: int,
    every: int,
    overrides: Sequence[str] = (),
    held_out: float = 0.1,
    seed: int = 0,
    report: Any = None,
    keys: Sequence[str] | None = None,
    device: str | torch.device = "cpu",
) -> list[dict[str, float]]:
    """How fast a fresh world model learns what eating does, from a DreamerV3 run's stored replay alone: no env,
    no actor, no critic, so world-model settings can be compared in minutes on the same data.

    Builds the run's world model anew (its config with ``overrides``, dotted ``algo`` keys such as
    ``model.stochastic=32`` or ``consume_share=0.5``), trains it for ``updates`` gradient steps on the first
    ``1 - held_out`` of the replay's rows (batches as the run drew them: ``batch_size`` sequences of
    ``sequence_length`` steps, ``consume_share`` of them around an eating step), and every ``every`` steps measures
    on the held-out rows' eating steps: from the posterior before each, one imagined step of every action
    (:func:`imagine_each_action`), and the decoded satiation plus hydration change of eating against the mean of the
    other four actions (``eat_effect``), beside the same on the eat actions that found nothing
    (``eat_effect_nothing``, which should stay near 0), the real change (``real_effect``) and the change decoded
    from the posterior that saw the observation after eating (``posterior_effect``: whether the latent holds it).
    ``keys``: the observation keys the new model sees (default: the run's; interoception is needed).  ``device``:
    where the model and its batches live (the replay stays memory-mapped; each batch is copied there).
    ``report(row)`` is called with each measurement.  The last row adds ``latent_auc_embedding``,
    ``latent_auc_state``, ``latent_auc_belief`` and ``latent_auc_belief_after_eat``: how well a logistic read-out of
    the trained encoder's embedding and latent on the observation an eat press was made on (and of the deterministic
    state the eat action leads to) tells a press that ate from a fruitless one, on the held-out rows
    (:func:`eat_success_readout` does the same from the observation itself)."""
    state, data, num_envs, rows = _run_replay(run_dir)
    cfg = OmegaConf.merge(OmegaConf.create(state["config"]).algo, OmegaConf.from_dotlist(list(overrides)))
    shapes = {k: tuple(v) for k, v in state["obs_shapes"].items()}
    if keys is not None:
        if "interoception" not in keys or not set(keys) <= set(shapes):
            raise ValueError(
                f"keys must include interoception and come from the run's {sorted(shapes)}, got {list(keys)}"
            )
        shapes = {k: v for k, v in shapes.items() if k in keys}
    torch.manual_seed(seed)
    model = make_model(cfg, shapes).to(device)
    loss = WorldModelLoss(cfg, model).to(device)
    optimizer = torch.optim.Adam(model.world_model_parameters(), lr=cfg.world_model.lr, eps=cfg.world_model.eps)
    length, context = cfg.sequence_length, 16
    split = int(rows * (1 - held_out))
    if split < length or rows - split < context + 1:
        raise ValueError(f"{run_dir}: {rows} rows per world are too few to hold out {held_out} of them")
    eaten = data["next", "consumed"].reshape(rows, num_envs)
    # an episode's first step was taken on its reset observation, which the replay does not store (the row before
    # holds the previous episode's last one): such steps are left out of the measurements below
    first = data["is_init"].reshape(rows, num_envs)
    train_eaten = eaten[:split].nonzero()
    consume = round(float(cfg.get("consume_share", 0.0)) * cfg.batch_size) if len(train_eaten) else 0
    gen = torch.Generator().manual_seed(seed)

    def sequences(starts: torch.Tensor, worlds: torch.Tensor, steps: int) -> TensorDictBase:
        batch = data[starts[:, None] + torch.arange(steps), worlds[:, None]].clone().to(device)
        batch["state"] = torch.zeros(*batch.shape, model.state_dim, device=device)
        batch["belief"] = torch.zeros(*batch.shape, model.belief_dim, device=device)
        return batch

    # held out: the context before each eating step (and each fruitless eat), the step itself last
    eat = ACTION_NAMES.index("eat")
    test_eaten = (eaten[split:] & ~first[split:]).nonzero()
    test_eaten = test_eaten[test_eaten[:, 0] >= context]
    pressed = ((data["action"][split:] == eat) & ~eaten[split:] & ~first[split:]).nonzero()
    pressed = pressed[pressed[:, 0] >= context]
    pressed = pressed[torch.randperm(len(pressed), generator=gen)[:256]]
    # the same measurement on eating steps the model trains on: learnt there but not held out is too few meals
    seen_eaten = train_eaten[(train_eaten[:, 0] >= context) & ~first[train_eaten[:, 0], train_eaten[:, 1]]]
    seen_eaten = seen_eaten[torch.randperm(len(seen_eaten), generator=gen)[:64]]

    def decoded(latent: Mapping[str, torch.Tensor]) -> torch.Tensor:  # satiation + hydration
        return model.decoder.vector("interoception", latent["state"], latent["belief"])[..., :2].sum(-1)

    @torch.no_grad()
    def eat_effect(where: torch.Tensor, offset: int = split) -> tuple[float, float, float]:
        if not len(where):
            return float("nan"), float("nan"), float("nan")
        batch = sequences(offset + where[:, 0] - context, where[:, 1], context + 1)
        nxt = world_model(model)(batch)["next"]
        # the posterior after the step before the action; the action's own step is the last row
        before = {k: nxt[k][:, -2] for k in LATENT}
        step = imagine_each_action(
            model.prior,
            before["state"],
            before["belief"],
            8,
            ev=lambda st, be: model.decoder.vector("interoception", st, be)[..., :2],
        )
        change = step["ev"].sum(-1) - decoded(before)[:, None]
        others = [i for i in range(NUM_ACTIONS) if i != eat]
        effect = float((change[:, eat] - change[:, others].mean(1)).mean())
        real = float(
            (batch["next", "interoception"][:, -1, :2] - batch["next", "interoception"][:, -2, :2])
            .float()
            .sum(-1)
            .mean()
        )
        # the same change read from the posteriors, which saw the observation after eating: what the latent holds
        seen = float((decoded({k: nxt[k][:, -1] for k in LATENT}) - decoded(before)).mean())
        return effect, real, seen

    rows_out: list[dict[str, float]] = []
    began = time.perf_counter()
    for update in range(updates + 1):
        if update % every == 0 or update == updates:
            model.eval()
            effect, real, seen = eat_effect(test_eaten)
            nothing, _, _ = eat_effect(pressed)
            trained, _, _ = eat_effect(seen_eaten, 0)
            row = {
                "updates": update,
                "seconds": time.perf_counter() - began,
                "eat_effect": effect,
                "eat_effect_nothing": nothing,
                "eat_effect_trained": trained,
                "real_effect": real,
                "posterior_effect": seen,
                "held_out_eating_steps": len(test_eaten),
                "world_model_parameters": sum(p.numel() for p in model.world_model_parameters()),
            }
            rows_out.append(row)
            if report is not None:
                report(row)
            model.train()
        if update == updates:
            break
        uniform = cfg.batch_size - consume
        starts = torch.randint(split - length + 1, (uniform,), generator=gen)
        worlds = torch.randint(num_envs, (uniform,), generator=gen)
        if consume:
            picks = train_eaten[torch.randint(len(train_eaten), (consume,), generator=gen)]
            offset = torch.randint(length, (consume,), generator=gen)
            starts = torch.cat([starts, (picks[:, 0] - offset).clamp(0, split - length)])
            worlds = torch.cat([worlds, picks[:, 1]])
        total, *_ = loss(sequences(starts, worlds, length))
        optimizer.zero_grad(set_to_none=True)
        total.backward()
        nn.utils.clip_grad_norm_(model.world_model_parameters(), cfg.world_model.grad_clip)
        optimizer.step()
    # what the trained latent keeps of "this press will eat": a logistic read-out, fitted on the training rows'
    # presses and scored on the held-out ones, as eat_success_readout does from the observation itself
    model.eval()
    presses = ((data["action"][context:] == eat) & ~first[context:]).nonzero()
    presses[:, 0] += context
    success = eaten[presses[:, 0], presses[:, 1]]
    fruitless = presses[~success]
    presses = torch.cat([presses[success], fruitless[torch.randperm(len(fruitless), generator=gen)[:1500]]])
    labels = eaten[presses[:, 0], presses[:, 1]]
    features: dict[str, list[torch.Tensor]] = {"embedding": [], "state": [], "belief": [], "belief_after_eat": []}
    with torch.no_grad():
        for chunk in presses.split(256):
            nxt = world_model(model)(sequences(chunk[:, 0] - context, chunk[:, 1], context + 1))["next"]
            features["embedding"].append(nxt["encoded_latents"][:, -2])  # the encoder's, before the latent
            features["state"].append(nxt["state"][:, -2])  # the posterior on the observation pressed on
            features["belief"].append(nxt["belief"][:, -2])
            features["belief_after_eat"].append(nxt["belief"][:, -1])  # the eat action taken, its outcome unseen
    rows_out[-1] |= {
        f"latent_auc_{name}": logistic_readout_auc(torch.cat(x).cpu(), labels, presses[:, 0] < split)
        for name, x in features.items()
    }
    return rows_out


def logistic_readout_auc(features: torch.Tensor, labels: torch.Tensor, fit: torch.Tensor) -> float:
    """How well a logistic regression from ``features`` [N, F], fitted (classes balanced, L-BFGS) on the rows where
    ``fit`` is true, tells ``labels`` apart on the other rows: the area under the ROC curve there (0.5: no better
    than chance; 1: perfectly), from the Mann-Whitney U of the scores.  NaN without both labels on both sides."""
    from scipy.stats import mannwhitneyu

    y = labels.bool()
    if not (y[fit].any() and (~y[fit]).any() and y[~fit].any() and (~y[~fit]).any()):
        return float("nan")
    x = features.double()
    mean, std = x[fit].mean(0), x[fit].std(0).clamp_min(1e-6)
    x = (x - mean) / std
    weights = torch.zeros(x.shape[1], dtype=x.dtype, requires_grad=True)
    bias = torch.zeros((), dtype=x.dtype, requires_grad=True)
    balance = (~y[fit]).sum() / y[fit].sum()
    optimizer = torch.optim.LBFGS([weights, bias], max_iter=200, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        loss = F.binary_cross_entropy_with_logits(x[fit] @ weights + bias, y[fit].double(), pos_weight=balance)
        loss = loss + 1e-4 * weights.pow(2).sum()
        loss.backward()
        return loss

    optimizer.step(closure)
    with torch.no_grad():
        score = (x[~fit] @ weights).numpy()
    test = y[~fit].numpy()
    u = mannwhitneyu(score[test], score[~test]).statistic
    return float(u / (test.sum() * (~test).sum()))


def eat_success_readout(run_dir: str | Path, held_out: float = 0.2) -> dict[str, Any]:
    """Whether the observations say when eating will work: for every stored eat press of a DreamerV3 run's replay,
    the observation it was pressed on, and whether it ate or drank.  A logistic read-out per vector key (and of all
    of them together) is fitted on the first ``1 - held_out`` of the rows; its held-out AUC says how much of "food
    within reach" the key carries, the information a world model needs to predict what eating does."""
    state, data, num_envs, rows = _run_replay(run_dir)
    # row r's action was taken on the observation stored as row r - 1's next; a reset's first one is not stored
    pressed = (data["action"][1:] == ACTION_NAMES.index("eat")) & ~data["is_init"][1:].reshape(rows - 1, num_envs)
    where = pressed.nonzero()
    ate = data["next", "consumed"].reshape(rows, num_envs)[1:][pressed]
    fit = where[:, 0] < int((rows - 1) * (1 - held_out))
    keys = [k for k in state["obs_keys"] if k != "pixels"]
    seen = {k: data["next", k][:-1][where[:, 0], where[:, 1]].float().reshape(len(where), -1) for k in keys}
    auc = {k: logistic_readout_auc(x, ate, fit) for k, x in seen.items()}
    auc["all of them"] = logistic_readout_auc(torch.cat(list(seen.values()), -1), ate, fit)
    return {"presses": len(where), "ate": int(ate.sum()), "held_out_ate": int(ate[~fit].sum()), "auc": auc}


def linear_probe_r2(
    features: torch.Tensor, target: torch.Tensor, fit: torch.Tensor, ridge: float = 1e-3
) -> torch.Tensor:
    """Per target column, the share of ``symlog(target)``'s variance (as the model codes the EVs) that a ridge
    regression from ``features`` explains on the rows where ``fit`` is false, fitted on the rows where it is true:
    1 holds it all, 0 nothing beyond the fitted mean (below 0: worse than that mean).  Features are standardised on
    the fitted rows; ``ridge`` times the number of fitted rows is the penalty."""
    x, y = features[fit].double(), symlog(target[fit].double())
    mean, std = x.mean(0), x.std(0).clamp_min(1e-6)  # a constant column: zeros, only the intercept is fitted
    x = torch.cat([(x - mean) / std, torch.ones(len(x), 1, dtype=x.dtype)], 1)
    gram = x.T @ x + ridge * len(x) * torch.eye(x.shape[1], dtype=x.dtype)
    weights = torch.linalg.solve(gram, x.T @ y)
    test = torch.cat([(features[~fit].double() - mean) / std, torch.ones(int((~fit).sum()), 1, dtype=x.dtype)], 1)
    truth = symlog(target[~fit].double())
    residual = ((test @ weights) - truth).pow(2).sum(0)
    spread = (truth - y.mean(0)).pow(2).sum(0).clamp_min(1e-12)
    return (1 - residual / spread).float()


def imagine_each_action(
    prior: Any, state: torch.Tensor, belief: torch.Tensor, samples: int = 8, **heads: Any
) -> dict[str, torch.Tensor]:
    """Every action taken once from each latent ``[N, ...]`` through ``prior`` (``(state, belief, one-hot) ->
    (logits, state, belief)``), the next latent drawn ``samples`` times: each head ``(state, belief) -> [N, ...]``
    read on it, averaged over the draws, as ``[N, actions, ...]``.  What imagination believes one action does."""
    out: dict[str, list[torch.Tensor]] = {name: [] for name in heads}
    for a in range(NUM_ACTIONS):
        onehot = one_hot_action(torch.full(state.shape[:-1], a, dtype=torch.long, device=state.device))
        totals: dict[str, torch.Tensor] = {}
        for _ in range(samples):
            _, next_state, next_belief = prior(state, belief, onehot)
            for name, head in heads.items():
                totals[name] = totals.get(name, 0) + head(next_state, next_belief) / samples
        for name in heads:
            out[name].append(totals[name])
    return {name: torch.stack(values, dim=1) for name, values in out.items()}


@torch.no_grad()
def imagined_action_values(
    run_dir: str | Path, sequences: int = 64, samples: int = 8, model_file: str | Path | None = None
) -> dict[str, Any]:
    """What a DreamerV3 run's world model and critic say each action is worth, from the posterior states of
    ``sequences`` replayed sequences (as :func:`ev_decoding_errors` picks them): one imagined step of every action,
    then the critic, ``r + γ·c·v`` (``samples`` draws of the next latent), beside the actor's probabilities and the
    EVs decoded before and after the step.  Grouped by what really followed each state: every state, the steps that
    ate or drank, the eat actions that found nothing, and the five steps before an eating step.  Where imagination
    ranks the actions the same way in every group, and eating raises no decoded EV where real eating did, the actor
    has nothing to learn from but a bias (docs/lab-notes.md, "What was tried on level 1-1")."""
    from evaaa import EV_NAMES

    state, cfg, model, batch, steps = _probe_replay(run_dir, sequences, model_file)
    nxt = world_model(model)(batch)["next"]
    # start from the posterior after each observation; what really followed it is the next row's action and outcome
    shape = (len(batch), batch.shape[1] - 1)
    latent = {k: nxt[k][:, :-1].reshape(-1, nxt[k].shape[-1]).float() for k in LATENT}
    action = batch["action"][:, 1:].reshape(-1)
    ate = batch["next", "consumed"][:, 1:].reshape(shape)
    fresh = batch["is_init"][:, 1:].reshape(-1)
    evs = nxt["interoception"].float()
    real_change = (evs[:, 1:] - evs[:, :-1]).reshape(-1, len(EV_NAMES))

    def reward(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return model.two_hot(model.reward(s, b)).squeeze(-1)

    def value(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return model.two_hot(model.value(s, b)).squeeze(-1)

    def going_on(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(model.cont(s, b)).squeeze(-1)

    def interoception(s: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return model.decoder.vector("interoception", s, b)

    step = imagine_each_action(
        model.prior,
        latent["state"],
        latent["belief"],
        samples,
        reward=reward,
        value=value,
        going_on=going_on,
        interoception=interoception,
    )
    q = step["reward"] + cfg.algo.gamma * step["going_on"] * step["value"]
    now = interoception(latent["state"], latent["belief"])
    ev_change = step["interoception"] - now[:, None]
    probs = model.actor.get_dist(TensorDict(latent, [len(action)])).probs
    norm = state["components"]["return_norm"]
    scale = max(float(norm["high"].max() - norm["low"].min()), 1.0) if "high" in norm else float("nan")
    before = torch.zeros(shape, dtype=torch.bool)
    for d in range(1, 6):
        before[:, :-d] |= ate[:, d:]
    ate, before = ate.reshape(-1), before.reshape(-1)
    eat = ACTION_NAMES.index("eat")
    groups = {
        "every state": ~fresh,
        "ate or drank": ate & ~fresh,
        "ate nothing": (action == eat) & ~ate & ~fresh,
        "1-5 steps before eating": before & ~ate & ~fresh,
    }
    result: dict[str, Any] = {"env_steps": steps, "sequences": len(batch), "return_scale": scale, "groups": {}}
    for name, mask in groups.items():
        if not bool(mask.any()):
            result["groups"][name] = {"states": 0}
            continue
        result["groups"][name] = {
            "states": int(mask.sum()),
            "policy": dict(zip(ACTION_NAMES, probs[mask].mean(0).tolist())),
            "value_over_mean": dict(zip(ACTION_NAMES, (q[mask] - q[mask].mean(1, keepdim=True)).mean(0).tolist())),
            "best_share": dict(
                zip(ACTION_NAMES, (torch.bincount(q[mask].argmax(1), minlength=NUM_ACTIONS) / int(mask.sum())).tolist())
            ),
            "ev_change": {
                a: dict(zip(EV_NAMES, ev_change[mask][:, i].mean(0).tolist())) for i, a in enumerate(ACTION_NAMES)
            },
            "real_ev_change": dict(zip(EV_NAMES, real_change[mask].mean(0).tolist())),
        }
    return result
