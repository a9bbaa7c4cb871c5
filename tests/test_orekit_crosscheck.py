"""Cross-check with Orekit itself (CS GROUP's flight dynamics library, through orekit-jpype
and Java 17): OEM, AEM and TDM written by fgnav are parsed by Orekit to the same numbers,
and the same messages written by Orekit are read by fgnav to Orekit's numbers. Slow (a JVM);
skipped where Java, orekit-jpype or Orekit's data set (../shared/data/orekit-data) is
missing. Run: python -m pytest -m slow tests/test_orekit_crosscheck.py -s (prints the
largest differences)."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from fgnav.io.aem import read_aem, write_aem
from fgnav.io.kvn import format_ccsds_epoch
from fgnav.io.oem import read_oem, write_oem
from fgnav.io.tdm import read_tdm, write_tdm
from fgnav.orbit import integrate_truth
from fgnav.time import add_seconds, parse_utc
from fgnav.vision.attitude import matrix_from_quat

import ccsds_corpus as C

pytestmark = pytest.mark.slow
X0 = np.array([6509244.371304875, 0.0, 3713244.835519765, -3737.397235776740, 0.0,
               8790.602460568101])
EPOCH0 = "2025-03-01T00:00:00Z"
OREKIT_DATA = next((p / "data" / "orekit-data" for p in C.CANDIDATES
                    if (p / "data" / "orekit-data").is_dir()), None)


@pytest.fixture(scope="module")
def orekit():
    if shutil.which("java") is None:
        pytest.skip("no Java")
    jp = pytest.importorskip("orekit_jpype", reason="orekit-jpype is not installed")
    if OREKIT_DATA is None:
        pytest.skip("no Orekit data set (../shared/data/orekit-data)")
    jp.initVM()
    from orekit_jpype.pyhelpers import setup_orekit_data
    setup_orekit_data(filenames=str(OREKIT_DATA), from_pip_library=False)
    import org.orekit as ok
    return ok


def _date(ok, t64):
    from org.orekit.time import AbsoluteDate, TimeScalesFactory
    return AbsoluteDate(format_ccsds_epoch(t64), TimeScalesFactory.getUTC())


def _parse(ok, kind, path):
    from org.orekit.data import DataSource
    from org.orekit.files.ccsds.ndm import ParserBuilder
    return getattr(ParserBuilder(), f"build{kind}Parser")().parseMessage(DataSource(str(path)))


def _write(ok, kind, msg, path):
    from java.lang import StringBuilder
    from org.orekit.files.ccsds.ndm import WriterBuilder
    from org.orekit.files.ccsds.utils.generation import KvnGenerator
    sb = StringBuilder()
    gen = KvnGenerator(sb, 25, str(path), 60.0, 0)
    getattr(WriterBuilder(), f"build{kind}Writer")().writeMessage(gen, msg)
    gen.close()
    path.write_text(str(sb.toString()))


def _oem_states(ok, oem, epoch0):
    t, x, covs = [], [], []
    ref = _date(ok, epoch0)
    for seg in oem.getSegments():
        for c in seg.getData().getCoordinates():
            t.append(c.getDate().durationFrom(ref))
            p, v = c.getPosition(), c.getVelocity()
            x.append([p.getX(), p.getY(), p.getZ(), v.getX(), v.getY(), v.getZ()])
        for cv in seg.getData().getCovarianceMatrices():
            m = cv.getCovarianceMatrix()
            covs.append((cv.getEpoch().durationFrom(ref),
                         np.array([[m.getEntry(i, j) for j in range(6)] for i in range(6)])))
    return np.array(t), np.array(x), covs


def test_oem_both_ways(orekit, tmp_path):
    t = np.arange(0.0, 1800.0, 60.0)
    x = integrate_truth(X0, t)
    rng = np.random.default_rng(1)
    A = rng.normal(size=(len(t), 6, 6)) * np.array([30, 30, 30, 0.03, 0.03, 0.03])
    P = A @ np.swapaxes(A, 1, 2)
    p = tmp_path / "fgnav.oem"
    write_oem(p, EPOCH0, t, x, P)
    ours = read_oem(p)
    ts, xs, covs = _oem_states(orekit, _parse(orekit, "Oem", p), ours.epoch0)
    dx = np.abs(xs - ours.x_eci).max(axis=0)
    dP = max(np.abs(Pk - ours.P_eci[i]).max() / np.abs(ours.P_eci[i]).max()
             for i, (_, Pk) in enumerate(covs))
    print(f"\nfgnav OEM -> Orekit: |dt| {np.abs(ts - ours.t_s).max():.3g} s, |dr| "
          f"{dx[:3].max():.3g} m, |dv| {dx[3:].max():.3g} m/s, covariance rel {dP:.3g}")
    assert np.abs(ts - ours.t_s).max() < 1e-9 and dx[:3].max() < 1e-9 and dx[3:].max() < 1e-12
    assert len(covs) == len(t) and dP < 1e-15
    # the corpus's ISS OEM as Orekit writes it, read by fgnav: Orekit's numbers
    iss = _parse(orekit, "Oem", C.CORPUS / "orekit/odm/oem/ISS.resampled.truncated.txt")
    q = tmp_path / "orekit.oem"
    _write(orekit, "Oem", iss, q)
    back = read_oem(q)
    ts, xs, _ = _oem_states(orekit, iss, back.epoch0)
    print(f"Orekit OEM -> fgnav: |dt| {np.abs(ts - back.t_s).max():.3g} s, |dx| "
          f"{np.abs(xs - back.x_eci).max():.3g} (m, m/s), {len(ts)} states")
    assert len(ts) == 25 and np.abs(ts - back.t_s).max() < 1e-9
    np.testing.assert_allclose(back.x_eci, xs, rtol=1e-15, atol=1e-9)


def _aem_rotations(ok, aem, epoch0):
    t, q = [], []
    ref = _date(ok, epoch0)
    for seg in aem.getSegments():
        for ac in seg.getData().getAngularCoordinates():
            r = ac.getRotation()
            t.append(ac.getDate().durationFrom(ref))
            q.append([r.getQ0(), r.getQ1(), r.getQ2(), r.getQ3()])
    return np.array(t), np.array(q)


def _angle(qa, qb):
    """Rotation angle between (N, 4) unit quaternions, sign-free: 4 asin(|qa - s qb| / 2),
    s the sign of qa . qb (well conditioned near zero, unlike 2 acos |qa . qb|)."""
    s = np.sign(np.sum(qa * qb, axis=1))[:, None]
    return 4 * np.arcsin(np.minimum(np.linalg.norm(qa - s * qb, axis=1) / 2, 1.0))


def test_aem_both_ways(orekit, tmp_path):
    rng = np.random.default_rng(2)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = np.array([matrix_from_quat(qk) for qk in q])
    t = np.arange(20) * 10.0
    p = tmp_path / "fgnav.aem"
    write_aem(p, EPOCH0, t, R)
    ours = read_aem(p)
    ts, qs = _aem_rotations(orekit, _parse(orekit, "Aem", p), ours.epoch0)
    err = _angle(qs, ours.q_wxyz).max()
    print(f"\nfgnav AEM -> Orekit: |dt| {np.abs(ts - ours.t_s).max():.3g} s, rotation "
          f"{err:.3g} rad")
    assert np.abs(ts - ours.t_s).max() < 1e-9 and err < 1e-14
    ex1 = _parse(orekit, "Aem", C.CORPUS / "orekit/adm/aem/AEMExample01.txt")
    w = tmp_path / "orekit.aem"
    _write(orekit, "Aem", ex1, w)
    back = read_aem(w)
    ts, qs = _aem_rotations(orekit, ex1, back.epoch0)
    err = _angle(qs, back.q_wxyz).max()
    print(f"Orekit AEM -> fgnav: |dt| {np.abs(ts - back.t_s).max():.3g} s, rotation {err:.3g} "
          f"rad, {len(ts)} attitudes")
    assert np.abs(ts - back.t_s).max() < 1e-9 and err < 1e-14


def test_tdm_both_ways(orekit, tmp_path):
    t = np.arange(0.0, 600.0, 30.0)
    x = integrate_truth(X0, t)
    u = -x[:, :3] / np.linalg.norm(x[:, :3], axis=1, keepdims=True)
    p = tmp_path / "fgnav.tdm"
    write_tdm(p, EPOCH0, t, u, 1e-4)
    ours = read_tdm(p)
    tdm = _parse(orekit, "Tdm", p)
    ref = _date(orekit, ours.epoch0)
    obs = {}
    for seg in tdm.getSegments():
        for o in seg.getData().getObservations():
            obs.setdefault(str(o.getType()), []).append(
                (o.getEpoch().durationFrom(ref), o.getMeasurement()))
    a1, a2 = np.array(obs["ANGLE_1"]), np.array(obs["ANGLE_2"])
    ra = np.arctan2(ours.xyz[:, 1], ours.xyz[:, 0]) % (2 * math.pi)
    dec = np.arcsin(ours.xyz[:, 2])
    d = max(np.abs(a1[:, 1] - ra).max(), np.abs(a2[:, 1] - dec).max())
    print(f"\nfgnav TDM -> Orekit: |dt| {np.abs(a1[:, 0] - ours.t_s).max():.3g} s, angles "
          f"{d:.3g} rad")
    assert np.abs(a1[:, 0] - ours.t_s).max() < 1e-9 and d < 1e-14
    w = tmp_path / "orekit.tdm"
    _write(orekit, "Tdm", tdm, w)
    back = read_tdm(w, sigma_rad=1e-4)
    err = np.abs(back.xyz - ours.xyz).max()
    print(f"Orekit TDM -> fgnav: |dt| {np.abs(back.t_s - ours.t_s).max():.3g} s, directions "
          f"{err:.3g}")
    assert np.abs(back.t_s - ours.t_s).max() < 1e-9 and err < 1e-12
    assert add_seconds(parse_utc(EPOCH0), 0.0) == back.epoch0
