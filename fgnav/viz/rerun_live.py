"""A live Rerun recording served to Rerun's web viewer while ``fgnav follow`` runs.

The recording is served over gRPC (``RecordingStream.serve_grpc``) and the web viewer is
served next to it (``rerun.serve_web_viewer``, connected to that stream); open the printed
address in a browser. Each epoch logs the online state (point in the 3-D scene, km, as
:mod:`fgnav.viz.rerun_log` draws it), its 1-sigma position and velocity, the update latency
and the live verdict; at the end the batch-smoothed history is logged into the same stream
with :func:`fgnav.viz.rerun_log.log_solution_to` (trajectory, covariance, residuals).
"""

from __future__ import annotations

import numpy as np

from fgnav.viz.rerun_log import log_solution_to

_KM = 1.0e-3
VERDICT_LEVEL = {"ok": "INFO", "suspect": "WARN", "failed": "ERROR"}


class LiveRecording:
    """``serve()`` then ``epoch(state)`` per epoch, ``verdict(event)``, ``final(solution)``."""

    def __init__(self, application_id: str = "fgnav follow"):
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(application_id)
        self.url = self.web = None

    def serve(self, grpc_port: int | None = None, web_port: int | None = None) -> str:
        """Start the gRPC server and the web viewer; returns the viewer's address."""
        rr = self.rr
        kw = {} if grpc_port is None else {"grpc_port": grpc_port}
        self.url = self.rec.serve_grpc(**kw)
        rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=self.url)
        port = web_port or 9090
        self.web = f"http://localhost:{port}/?url={self.url}"
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        return self.web

    def _time(self, ns: int, t_s: float) -> None:
        """The timelines of :func:`fgnav.viz.rerun_log.log_solution`: ``utc`` and ``t_s``."""
        self.rec.set_time("utc", timestamp=np.datetime64(int(ns), "ns"))
        self.rec.set_time("t_s", duration=float(t_s))

    def epoch(self, state) -> None:
        """One online :class:`fgnav.online.navigator.State`."""
        rr = self.rr
        self._time(state.ns, state.t_s)
        sig = np.sqrt(np.maximum(np.diag(state.P), 0.0))
        self.rec.log("world/online/state", rr.Points3D([state.x[:3] * _KM],
                                                        colors=[[255, 120, 0]]))
        self.rec.log("online/sigma_position_m", rr.Scalars(float(np.linalg.norm(sig[:3]))))
        self.rec.log("online/sigma_velocity_mps", rr.Scalars(float(np.linalg.norm(sig[3:]))))
        self.rec.log("online/latency_ms", rr.Scalars(state.latency_s * 1e3))

    def verdict(self, state, event: dict) -> None:
        """A change of the live verdict (the JSON event of ``fgnav follow``) at ``state``."""
        self._time(state.ns, state.t_s)
        self.rec.log("online/integrity", self.rr.TextLog(
            f"{event['from']} -> {event['to']}", level=VERDICT_LEVEL.get(event["to"], "INFO")))

    def final(self, solution, measurements=None, residual_t_s=None) -> list[str]:
        """The smoothed history into the same stream."""
        return log_solution_to(self.rec, solution, measurements=measurements,
                               residual_t_s=residual_t_s)

    def close(self) -> None:
        self.rec.flush()
