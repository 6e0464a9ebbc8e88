"""What the frontier policy is doing: exploring, closing a loop or backing off (an explicit
state instead of flags spread over the policy).

The planner heads for one of two kinds of goal — the frontier of best utility
(:attr:`Mode.EXPLORE`) or, during an active loop closing, a place where the pose was well
known (:attr:`Mode.CLOSE_LOOP`); a back-off (:attr:`Mode.BACK_OFF`) interrupts either for a
few steps, driving away from a robot it stalled against, or, stalled with no path, out of a
pocket the way its own map lets it drive (:meth:`policies.frontier.FrontierPolicy._escape`),
and then the heading goes on.
:class:`ModeState` holds the mode and the facts its transitions need; the policy decides when
they happen (:mod:`policies.frontier`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = ["BACK_OFF_STEPS", "BackOff", "Mode", "ModeState"]

#: Steps a stalled robot drives away (from another robot, or out of a pocket) before it plans again.
BACK_OFF_STEPS = 8


class Mode(enum.Enum):
    """What the robot is doing."""

    EXPLORE = "explore"  # to the frontier of best utility
    CLOSE_LOOP = "close_loop"  # back to a well-localised place, to re-observe its walls
    BACK_OFF = "back_off"  # away from a robot it stalled against, or out of a pocket


@dataclass(frozen=True)
class BackOff:
    """A back-off: drive toward own-frame ``direction`` (rad) until step ``until``."""

    direction: float
    until: int


@dataclass
class ModeState:
    """The mode and its bookkeeping; ``heading`` is :attr:`Mode.EXPLORE` or
    :attr:`Mode.CLOSE_LOOP`, ``back_off`` the back-off under way (None: none)."""

    heading: Mode = Mode.EXPLORE
    back_off: BackOff | None = None
    resume: tuple[int, int] | None = None  # the frontier goal a loop closing left
    rest_until: int = 0  # no new loop closing before this step
    closings: int = 0  # loop closings started this episode
    closing_steps: int = 0  # steps spent closing loops this episode
    closing_since: int = 0  # the step the loop closing under way started

    @property
    def mode(self) -> Mode:
        """What the robot is doing now: a back-off overrides the heading."""
        return Mode.BACK_OFF if self.back_off is not None else self.heading

    @property
    def closing(self) -> bool:
        """Whether a loop closing is under way (backing off or not)."""
        return self.heading is Mode.CLOSE_LOOP

    def start_closing(self, resume: tuple[int, int] | None, step: int) -> None:
        """Head back to an anchor from step ``step``, remembering the frontier goal ``resume``
        to return to."""
        self.heading, self.resume = Mode.CLOSE_LOOP, resume
        self.closings += 1
        self.closing_since = step

    def stop_closing(self, step: int, rest: int) -> None:
        """Explore again; no new loop closing for ``rest`` steps after ``step``."""
        self.heading, self.rest_until = Mode.EXPLORE, step + rest

    def take_resume(self) -> tuple[int, int] | None:
        """The frontier goal to return to after a loop closing (once)."""
        resume, self.resume = self.resume, None
        return resume
