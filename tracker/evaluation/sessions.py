"""Simulated evaluation sessions: six users with different speed, occlusion and out-of-view behaviour.

The session lists mirror the thesis's datasets (spec section 18.5): guidance 15 recordings (Table 6.1's
user/recording pattern), guess 16 (Table 6.2: users 1–5 build each of the 3 structures, user 6 builds
structure 1), learning 12 (each user builds a 5-word and a 4-word sentence). Each session is one run of the
built-in simulator (:class:`tracker.sources.simulator.SimulatedTable`) with a seed of its own.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class UserProfile:
    """A simulated user: hand ``speed`` factor, ``occlusion`` 0..2 and out-of-view ``excursions``."""

    user: int
    speed: float
    occlusion: float
    excursions: bool

    @property
    def speed_label(self) -> str:
        return "low" if self.speed < 1.75 else "medium" if self.speed < 2.25 else "high"

    @property
    def occlusion_label(self) -> str:
        return "few" if self.occlusion < 0.75 else "several" if self.occlusion < 1.3 else "many"


USERS = {
    1: UserProfile(1, 1.5, 0.5, False),
    2: UserProfile(2, 2.5, 0.5, False),
    3: UserProfile(3, 2.0, 1.0, False),
    4: UserProfile(4, 2.5, 1.6, False),
    5: UserProfile(5, 1.5, 0.5, True),
    6: UserProfile(6, 2.0, 1.0, True),
}
"""Speeds 1.5 / 2 / 2.5 (low / medium / high) give sessions of roughly 12–22 s, like the thesis's."""


@dataclass(frozen=True)
class SessionSpec:
    experiment: str
    index: int
    user: int
    recording: int
    scenario: str
    task_id: str
    seed: int
    truth: str | None = None  # guess: true structure name; learning: sentence index as text
    speed: float = 1.0
    occlusion: float = 1.0
    excursions: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


def _spec(exp: str, i: int, user: int, rec: int, scenario: str, task_id: str, truth: str | None = None) -> SessionSpec:
    u = USERS[user]
    seed = 1000 * {"guidance": 1, "guess": 2, "learning": 3}[exp] + 10 * user + rec
    return SessionSpec(exp, i, user, rec, scenario, task_id, seed, truth, u.speed, u.occlusion, u.excursions)


GUESS_STRUCTURES = {1: "T-tower", 2: "L", 3: "tower-with-wings"}


def guidance_sessions() -> list[SessionSpec]:
    pattern = [(1, 1), (1, 2), (1, 3), (2, 1), (2, 2), (2, 3), (3, 1), (3, 2), (3, 3), (4, 1), (5, 1), (5, 2),
               (5, 3), (6, 1), (6, 2)]
    return [_spec("guidance", i, u, r, "guidance-demo", "guidance-5-cubes") for i, (u, r) in enumerate(pattern)]


def guess_sessions() -> list[SessionSpec]:
    pattern = [(u, s) for u in range(1, 6) for s in (1, 2, 3)] + [(6, 1)]
    return [_spec("guess", i, u, s, f"guess-{s}", "guess-structures", GUESS_STRUCTURES[s])
            for i, (u, s) in enumerate(pattern)]


def learning_sessions() -> list[SessionSpec]:
    out = []
    for u in range(1, 7):
        for words in (5, 4):
            i = len(out)
            n_sent = 3 if words == 5 else 4
            out.append(_spec("learning", i, u, words, f"learning-{words}", f"learning-{words}-words",
                             str((u - 1) % n_sent)))
    return out


def sessions_for(experiment: str) -> list[SessionSpec]:
    return {"guidance": guidance_sessions, "guess": guess_sessions, "learning": learning_sessions}[experiment]()
