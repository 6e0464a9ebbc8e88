"""Parameter sharing for Stable-Baselines3: every robot is one slot of a vectorised env.

The chain is ``parallel_env`` → :class:`FixedAgents` → SuperSuit's
``pettingzoo_env_to_vec_env_v1`` → ``concat_vec_envs_v1(..., base_class="stable_baselines3")``
→ :class:`SB3VecEnvAdapter` → SB3's ``VecMonitor``. Two pieces of ours are needed, because
with SuperSuit 3.11 and SB3 2.x:

* ``PPO(..., seed=s)`` calls ``venv.seed(s)``; SuperSuit's ``SB3VecEnvWrapper`` inherits
  ``VecEnvWrapper.seed``, which forwards to ``ConcatVecEnv.seed`` / ``ProcConcatVec.seed``:
  neither exists (Gymnasium 1.x vector envs have no ``seed``), hence ``AttributeError:
  'ConcatVecEnv' object has no attribute 'seed'``. The wrapper also skips ``VecEnv.__init__``
  (no ``_seeds``/``_options``), drops the seeds SB3 hands to ``reset``, returns the
  multi-process reset infos still compressed, answers ``get_attr("render_mode")`` with a
  list of lists, and reports truncation as termination (no ``TimeLimit.truncated``, so SB3
  cannot bootstrap at ``max_steps``). :class:`SB3VecEnvAdapter` fixes all of these.
* ``pettingzoo_env_to_vec_env_v1`` asserts that no agent leaves mid-episode, and
  SuperSuit's ``black_death_v3`` ends the episode only when every agent is terminated *and*
  truncated (so never at ``max_steps``: the next step has no live agent and the env raises).
  :class:`FixedAgents` keeps every robot present by design instead.

With worker processes, :func:`vectorise` builds SuperSuit's ``ProcConcatVec`` itself, for two
reasons. SuperSuit's ``concat_vec_envs_v1`` seeds worker ``i`` with ``seed + i`` and its
``k``-th env copy with that plus ``k``: with more copies than workers two copies got the same
seed (4 copies on 2 workers: ``s, s+1, s+1, s+2``), and so the same maps and layouts for the
whole run. Here copy ``k`` gets ``seed + k`` with any number of workers (:class:`_Copies`), as
in one process. And each worker plays one step of a copy in a thread as soon as it is built
(:meth:`_Copies.warm`), so that it loads its compiled kernels while the parent builds the model
(PPO's build imports ``torch._dynamo``, seconds) instead of at the first reset, when the parent
waits for it; the seeded reset that follows starts the episode afresh. SuperSuit's
constructor also built one more copy in the parent only to read its metadata.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import supersuit as ss
from gymnasium import spaces
from gymnasium.vector.utils import create_empty_array
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices
from supersuit.vector import ConcatVecEnv
from supersuit.vector.multiproc_vec import ProcConcatVec, decompress_info
from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper
from supersuit.vector.vector_constructors import vec_env_args

from polyslam_env.environment.parallel import parallel_env

if TYPE_CHECKING:
    from polyslam_env.environment.config import EnvConfig

__all__ = ["FixedAgents", "SB3VecEnvAdapter", "make_vec_env", "vectorise"]

Step = tuple[
    dict[str, np.ndarray],
    dict[str, float],
    dict[str, bool],
    dict[str, bool],
    dict[str, dict[str, Any]],
]


class FixedAgents(ParallelEnv[str, np.ndarray, np.ndarray]):
    """Every robot stays in ``agents`` for the whole episode, with actions in [−1, 1]².

    A robot that fails is reported ``terminated`` at its fault step (its real last
    observation in ``info["terminal_observation"]``, zeros as the observation), and from then
    on gets zero observations and rewards, empty infos and no done flag, while its actions
    are dropped; when the team episode ends, its slot is reported terminated too. Each slot
    thus sees a sequence of proper episodes (the dead slot's filler episode is all zeros).

    Actions are normalised: ``a ∈ [−1, 1]²`` drives ``low + (a + 1)/2 · (high − low)`` of the
    robot's action space (PPO's Gaussian works best on a unit box). Vector observations and
    continuous actions only.
    """

    def __init__(self, env: ParallelEnv[str, Any, Any]) -> None:
        self.env = env
        self.possible_agents = list(env.possible_agents)
        self.agents: list[str] = []
        self.metadata = env.metadata
        self.render_mode = getattr(env, "render_mode", None)
        obs = env.observation_space(self.possible_agents[0])
        act = env.action_space(self.possible_agents[0])
        if not isinstance(obs, spaces.Box) or not isinstance(act, spaces.Box):
            raise ValueError(
                "FixedAgents needs Box observations and actions (observation.mode='vector',"
                f" action.mode='continuous'); got {obs} and {act}"
            )
        self._obs_space = obs
        self._act_low, self._act_high = act.low.astype(float), act.high.astype(float)  # (2,)
        self._unit = spaces.Box(-1.0, 1.0, act.shape, dtype=np.float32)

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._unit

    def physical(self, action: np.ndarray) -> np.ndarray:  # (2,)
        """The physical (v, ω) of a normalised action."""
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        return self._act_low + 0.5 * (a + 1.0) * (self._act_high - self._act_low)

    def _zeros(self) -> np.ndarray:
        return np.zeros(self._obs_space.shape, dtype=np.float32)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        obs, infos = self.env.reset(seed=seed, options=options)
        self.agents = self.possible_agents[:]
        full = {a: obs.get(a, self._zeros()) for a in self.agents}
        return full, {a: infos.get(a, {}) for a in self.agents}

    def step(self, actions: Mapping[str, Any]) -> Step:
        live = list(self.env.agents)
        obs, rew, term, trunc, info = self.env.step({a: self.physical(actions[a]) for a in live})
        over = not self.env.agents
        out: Step = ({}, {}, {}, {}, {})
        for a in self.possible_agents:
            if a not in live:  # failed earlier: filler
                out[0][a], out[1][a], out[4][a] = self._zeros(), 0.0, {}
                out[2][a], out[3][a] = over, False
                continue
            out[0][a], out[1][a], out[4][a] = obs[a], float(rew[a]), info[a]
            out[2][a], out[3][a] = bool(term[a]), bool(trunc[a])
            if not over and (term[a] or trunc[a]):  # failed now, the others go on
                out[4][a] = {**info[a], "terminal_observation": obs[a]}
                out[0][a] = self._zeros()
        self.agents = [] if over else self.possible_agents[:]
        return out

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()

    @property
    def unwrapped(self) -> ParallelEnv[str, Any, Any]:
        return self.env.unwrapped


class SB3VecEnvAdapter(SB3VecEnvWrapper):
    """SuperSuit's ``SB3VecEnvWrapper`` made a complete SB3 2.x ``VecEnv``.

    ``seed(s)`` stores per-slot seeds ``s + i`` as SB3 does; the next ``reset`` passes the
    first slot's seed down (SuperSuit seeds sub-env ``k`` with it plus ``k``). Build it with
    :meth:`from_supersuit` on what ``concat_vec_envs_v1(..., "stable_baselines3")`` returns.
    """

    def __init__(self, venv: Any) -> None:
        super().__init__(venv)
        VecEnv.__init__(self, venv.num_envs, venv.observation_space, venv.action_space)

    @classmethod
    def from_supersuit(cls, wrapper: SB3VecEnvWrapper) -> SB3VecEnvAdapter:
        """The adapter around the Gymnasium vector env inside SuperSuit's wrapper."""
        return cls(wrapper.venv)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        return VecEnv.seed(self, seed)

    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        VecEnv.set_options(self, options)

    def reset(self) -> np.ndarray:
        seed, options = self._seeds[0], self._options[0] or None
        obs, infos = self.venv.reset(seed=seed, options=options)
        if isinstance(self.venv, ProcConcatVec):  # its reset infos come back compressed
            infos = decompress_info(self.num_envs, self.venv.idx_starts, infos)
        self.reset_infos = [dict(i) for i in infos]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        obs, rewards, terms, truncs, infos = self.venv.step_wait()
        terms, truncs = np.asarray(terms, dtype=bool), np.asarray(truncs, dtype=bool)  # (S,)
        out = []
        for i, info in enumerate(infos):
            info = dict(info)  # SuperSuit may share one {} between slots
            info["TimeLimit.truncated"] = bool(truncs[i] and not terms[i])
            out.append(info)
        return obs, np.asarray(rewards, dtype=np.float32), terms | truncs, out

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        if attr_name == "render_mode":
            return [self.venv.render_mode for _ in self._get_indices(indices)]
        return super().get_attr(attr_name, indices)

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        flags = list(self.venv.env_is_wrapped(wrapper_class))
        return [bool(flags[i]) for i in self._get_indices(indices)]

    def render(self, mode: str | None = None) -> np.ndarray | None:
        return self.venv.render()


def make_vec_env(
    config: EnvConfig | Mapping[str, Any] | str | Path | None,
    num_envs: int,
    num_cpus: int = 0,
    seed: int | None = None,
    monitor: bool = True,
    **overrides: Any,
) -> VecEnv:
    """An SB3 ``VecEnv`` of ``num_envs`` copies of the env, one slot per robot (so
    ``num_envs · num_robots`` slots); ``num_cpus`` > 0 runs them in that many processes.

    ``seed`` is applied at the first reset (``PPO(seed=...)`` overrides it). ``monitor``
    adds SB3's ``VecMonitor`` (episode returns per slot for the logs).
    """
    if num_envs < 1:
        raise ValueError(f"num_envs: must be >= 1, got {num_envs}")
    team = FixedAgents(parallel_env(config, **overrides))
    return vectorise(team, num_envs, num_cpus=num_cpus, seed=seed, monitor=monitor)


def vectorise(
    team: ParallelEnv[str, Any, Any],
    num_envs: int,
    num_cpus: int = 0,
    seed: int | None = None,
    monitor: bool = True,
) -> VecEnv:
    """An SB3 ``VecEnv`` of ``num_envs`` copies of ``team``, a parallel env whose agents never
    leave mid-episode (:class:`FixedAgents`, or the goal-choice env of ``polyslam train``);
    arguments as :func:`make_vec_env`."""
    if num_envs < 1:
        raise ValueError(f"num_envs: must be >= 1, got {num_envs}")
    markov = ss.pettingzoo_env_to_vec_env_v1(team)
    workers = min(num_cpus, num_envs)
    if workers <= 1:
        wrapper = ss.concat_vec_envs_v1(markov, num_envs, base_class="stable_baselines3")
        venv: VecEnv = SB3VecEnvAdapter.from_supersuit(wrapper)
    else:
        venv = SB3VecEnvAdapter(_processes(markov, num_envs, workers))
    if seed is not None:
        venv.seed(seed)
    return VecMonitor(venv) if monitor else venv


class _Copies(ConcatVecEnv):
    """One worker's env copies, ``first`` … of all: a seeded reset gives copy ``first + k`` the
    seed ``seed + first + k`` (module doc). ``ProcConcatVec`` hands worker ``i`` the seed
    ``seed + i``, so ``offset = first − i``.

    :meth:`warm` resets and steps the first copy once (zero actions) in a thread, so that the
    worker loads its compiled kernels while it waits for its first instruction; every method
    that touches the copies waits for that thread first (and raises what it raised)."""

    def __init__(self, copies: list[Callable[[], Any]], offset: int) -> None:
        super().__init__(copies)
        self.offset = offset
        self._warming: threading.Thread | None = None
        self._warm_error: BaseException | None = None

    def warm(self) -> None:
        """Start the first copy's warm-up step (class doc)."""

        def play() -> None:
            try:
                first = self.vec_envs[0]
                first.reset(seed=0)
                first.step(create_empty_array(first.action_space, n=first.num_envs))
            except BaseException as error:  # raised again by the next call that waits
                self._warm_error = error

        self._warming = threading.Thread(target=play, name="polyslam-warm-up", daemon=True)
        self._warming.start()

    def _ready(self) -> None:
        if self._warming is not None:
            self._warming.join()
            self._warming = None
            if self._warm_error is not None:
                raise self._warm_error

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        self._ready()
        return super().reset(seed=None if seed is None else seed + self.offset, options=options)

    def step(self, actions: Any) -> Any:
        self._ready()
        return super().step(actions)

    def render(self) -> Any:
        self._ready()
        return super().render()

    def close(self) -> None:
        self._ready()
        super().close()


def _worker_copies(markov: Any, count: int, offset: int) -> _Copies:
    """In a worker process: ``count`` copies of ``markov``, the first warming up (its kernels
    loaded while the parent builds the model: module doc)."""
    copies = _Copies(vec_env_args(markov, count)[0], offset)  # SuperSuit's own copies
    copies.warm()
    return copies


def _processes(markov: Any, num_envs: int, workers: int) -> ProcConcatVec:
    """``num_envs`` copies of ``markov`` in ``workers`` processes, as SuperSuit splits them
    (consecutive copies, ``ceil(num_envs / workers)`` per worker), each copy seeded by its own
    index (module doc)."""
    per = -(-num_envs // workers)
    firsts = range(0, num_envs, per)
    build = [
        functools.partial(_worker_copies, markov, min(per, num_envs - first), first - i)
        for i, first in enumerate(firsts)
    ]
    return ProcConcatVec(
        build, markov.observation_space, markov.action_space, num_envs * markov.num_envs,
        markov.metadata,
    )  # fmt: skip
