"""``sim://`` backend: the built-in simulated boards (``sim://simo``, ``sim://d2g``).

Options: ``scenario`` (built-in name or path to a TOML file), ``seed``, ``realtime`` (1: the board
free-runs on the host clock, a late reader sees the newest frame and counts the ones it missed;
0: frames come back to back as fast as they are read, stamped on the board's timeline: time of
opening + frame counter x period), ``loop`` (restart the scenario at its end
instead of ending the source), ``frames`` (stop after this many; default: the scenario's duration), ``tx_power``
(``sim://d2g`` only: the board's TX power level 0..7, as ``d2g://`` sets it; default: the scenario's, else 7).
"""

from __future__ import annotations

from typing import Any

from hal.base import RadarSource, RawRead
from hal.clock import MonotonicClock
from hal.errors import SourceClosedError, SourceUrlError
from hal.registry import Option, SourceUrl, parse_bool, resolve_options

DEFAULT_SCENARIO = {"simo": "highway4", "d2g": "tavanti-test1"}


class SimSource(RadarSource):
    scheme = "sim"
    options = {
        "scenario": Option(str, None, "built-in scenario name or .toml path"),
        "seed": Option(int, None, "random seed (default: the scenario's)"),
        "realtime": Option(parse_bool, True, "1 = free-running board on the host clock, 0 = as fast as read"),
        "loop": Option(parse_bool, False, "restart the scenario when it ends"),
        "frames": Option(int, 0, "stop after this many frames (0 = the scenario's duration)"),
        "tx_power": Option(int, None, "sim://d2g: TX power level 0..7 (default: the scenario's, else 7 = full)"),
    }

    def __init__(
        self,
        board: str,
        scenario: str | None = None,
        seed: int | None = None,
        realtime: bool = True,
        loop: bool = False,
        frames: int = 0,
        tx_power: int | None = None,
        clock: Any = None,
    ) -> None:
        from hw_sim.boards import board_for  # lazy: only simulated backends need hw_sim

        self._clock = clock or MonotonicClock()
        super().__init__(clock_ns=self._clock.now_ns)
        try:
            self._board = board_for(board)
        except ValueError as exc:
            raise SourceUrlError(f"{exc} (e.g. sim://simo or sim://d2g)") from None
        self.board_name = board
        self.scenario_name = scenario or DEFAULT_SCENARIO[board]
        self.seed_opt = seed
        self.realtime = realtime
        self.paces_itself = realtime
        self.loop = loop
        self.max_frames = frames
        if tx_power is not None:
            from hw_sim.boards import D2G_MAX_TX_POWER

            if board != "d2g":
                raise SourceUrlError(f"tx_power is a Distance2Go setting; sim://{board} has none")
            if not 0 <= tx_power <= D2G_MAX_TX_POWER:
                raise SourceUrlError(f"tx_power={tx_power} out of range 0..{D2G_MAX_TX_POWER}")
        self.tx_power = tx_power
        self._sim = None
        self._scenario = None

    @classmethod
    def from_url(cls, url: SourceUrl, overrides: dict[str, Any]) -> "SimSource":
        clock = overrides.pop("clock", None)
        opts = resolve_options(url, cls.options, overrides)
        board = url.target.strip("/")
        if not board:
            raise SourceUrlError("sim:// needs a board: sim://simo or sim://d2g")
        return cls(board, clock=clock, **opts)

    @property
    def frontend(self):
        return self._board.frontend

    @property
    def max_tx_power(self) -> int | None:
        """The highest TX power level of the ``tx_power`` option (the Distance2Go's 7; None: the board has none)."""
        if self.board_name != "d2g":
            return None
        from hw_sim.boards import D2G_MAX_TX_POWER

        return D2G_MAX_TX_POWER

    @property
    def scenario(self):
        return self._scenario

    def _open(self) -> None:
        from hw_sim.scenario import ScenarioError, load_scenario
        from hw_sim.simulator import FrameSimulator

        try:
            sc = load_scenario(self.scenario_name)
        except ScenarioError as exc:
            raise SourceUrlError(str(exc)) from None
        if sc.board != self.board_name:
            raise SourceUrlError(
                f"scenario {sc.name!r} is for board {sc.board!r}, not {self.board_name!r}: use sim://{sc.board}?scenario={sc.name}"
            )
        self._scenario = sc
        seed = sc.seed if self.seed_opt is None else self.seed_opt
        self.seed = seed
        self._board = sc.sim_board()
        if self.tx_power is not None:  # the URL's level instead of the scenario's
            from hw_sim.boards import with_tx_power

            self._board = with_tx_power(self._board, self.tx_power)
        self._sim = FrameSimulator(self._board, sc.build_scene(seed), seed)
        period = self.frontend.waveform.frame_period_s
        self._scenario_frames = max(1, int(round(sc.duration_s / period)))
        self._limit = self.max_frames or (0 if self.loop else self._scenario_frames)
        self._period_ns = int(round(period * 1e9))
        self._t0_ns = self._clock.now_ns()
        self._next = 0

    def _read_raw(self, timeout_s: float | None) -> RawRead | None:
        n = self._next
        if self.realtime:
            now = self._clock.now_ns()
            due = self._t0_ns + (n + 1) * self._period_ns  # frame n is complete one period after it starts
            if due > now:
                if timeout_s is not None and due > now + timeout_s * 1e9:
                    self._clock.sleep_until_ns(now + int(timeout_s * 1e9))
                    return None
                self._clock.sleep_until_ns(due)
            # the board free-runs: a late reader gets the newest complete frame
            n = max(n, (self._clock.now_ns() - self._t0_ns) // self._period_ns - 1)
        if self._limit and n >= self._limit:
            raise SourceClosedError(f"simulation ended after {self._limit} frames")
        self._next = n + 1
        k = n % self._scenario_frames if self.loop else n
        f = self._sim.frame(k)
        # unpaced, the host clock runs much faster than the board's: stamp the frame on the board's
        # timeline (open time + n periods) so that trackers and interval statistics see real time
        t_ns = None if self.realtime else self._t0_ns + n * self._period_ns
        return RawRead(seq=n, i=f.i, q=f.q, truth=f.truth, t_ns=t_ns, meta={"sim_t_s": f.t_s})

    def _close(self) -> None:
        self._sim = None
