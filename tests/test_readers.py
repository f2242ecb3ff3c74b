"""Readers of outside formats against independent values: pyubx2 on the walk's UBX capture,
the printed columns of RTKLIB's .pos, the GEONET RINEX 2 pair and the same pair written as
RINEX 3, KF-GINS and CSV text written here from known arrays."""

from pathlib import Path

import numpy as np
import pytest

from gpsins import _core
from gpsins.gnss import spp
from gpsins.evaluate import c_en
from gpsins.formats.common import ReaderError
from gpsins.formats import imu_csv, kfgins, rinex, rtklib_pos, ubx
from gpsins.formats import common
from gpsins.formats import gpstime
from gpsins.formats.gpstime import UNIX_TO_GPS_S, gps_seconds

WALK = Path(__file__).parent / "data" / "walk_0827"
UBX_FILE = WALK / "gnss_1730.ubx"
POS_FILE = WALK / "gnss_1730_sf.pos"
WEEK = 2381
GEOID_M = -21.387  # the geoid's height above the ellipsoid at the walk: NAV-PVT's height - hMSL


@pytest.fixture(scope="module")
def walk_ubx():
    return ubx.read(UBX_FILE)


@pytest.fixture(scope="module")
def pyubx2_messages():
    pyubx2 = pytest.importorskip("pyubx2")
    with open(UBX_FILE, "rb") as f:
        return [m for _, m in pyubx2.UBXReader(f, protfilter=pyubx2.UBX_PROTOCOL, quitonerror=0)]


# --- UBX -----------------------------------------------------------------------------------------------------

def test_ubx_frames_and_fields_match_pyubx2(walk_ubx, pyubx2_messages):
    from collections import Counter
    theirs = Counter(m.identity for m in pyubx2_messages)
    assert theirs == Counter({"RXM-SFRBX": 2328, "RXM-RAWX": 536, "NAV-PVT": 536})  # the README's counts
    assert {k: walk_ubx.counts[k] for k in theirs} == dict(theirs)
    assert walk_ubx.damage == []  # everything between frames is whole NMEA sentences
    assert walk_ubx.counts["NMEA sentences"] > 0

    rawx = [m for m in pyubx2_messages if m.identity == "RXM-RAWX"]
    rows = [(m.rcvTow, m.week, getattr(m, f"prMes_{k:02d}"), getattr(m, f"cpMes_{k:02d}"), getattr(m, f"doMes_{k:02d}"),
             getattr(m, f"gnssId_{k:02d}"), getattr(m, f"svId_{k:02d}"), getattr(m, f"sigId_{k:02d}"),
             getattr(m, f"locktime_{k:02d}"), getattr(m, f"cno_{k:02d}"), getattr(m, f"prValid_{k:02d}"),
             getattr(m, f"cpValid_{k:02d}"))
            for m in rawx for k in range(1, m.numMeas + 1)]
    ref = np.array(rows, dtype=float)
    r = walk_ubx.rawx
    assert len(r) == len(ref)
    np.testing.assert_allclose(walk_ubx.rawx_t_abs, ref[:, 1] * 604800 + ref[:, 0], rtol=0, atol=1e-6)
    for j, name in enumerate(("pr_m", "cp_cycles", "doppler_hz", "gnss", "sv", "sig", "lock_ms", "cn0_dbhz"), 2):
        np.testing.assert_array_equal(r[name].astype(float), ref[:, j], err_msg=name)
    np.testing.assert_array_equal(r["trk"] & 1, ref[:, 10])
    np.testing.assert_array_equal((r["trk"] >> 1) & 1, ref[:, 11])

    pvt = [m for m in pyubx2_messages if m.identity == "NAV-PVT"]
    p = walk_ubx.pvt
    assert len(p) == len(pvt)
    np.testing.assert_array_equal(p["itow_ms"], [m.iTOW for m in pvt])
    np.testing.assert_allclose(p["lat"] * 1e-7, [m.lat for m in pvt], rtol=0, atol=1e-12)
    np.testing.assert_allclose(p["lon"] * 1e-7, [m.lon for m in pvt], rtol=0, atol=1e-12)
    for ours, theirs in (("height_mm", "height"), ("h_acc_mm", "hAcc"), ("v_acc_mm", "vAcc"), ("vel_n", "velN"),
                         ("vel_e", "velE"), ("vel_d", "velD"), ("s_acc", "sAcc"), ("fix_type", "fixType"),
                         ("num_sv", "numSV"), ("nano", "nano")):
        np.testing.assert_array_equal(p[ours], [getattr(m, theirs) for m in pvt], err_msg=ours)
    np.testing.assert_array_equal((p["flags"] >> 6) & 3, [m.carrSoln for m in pvt])
    np.testing.assert_array_equal(p["flags"] & 1, [m.gnssFixOk for m in pvt])
    np.testing.assert_allclose(p["height_mm"] - p["hmsl_mm"], GEOID_M * 1000, atol=1)

    # Fixes: times from the UTC date + nano and the leap seconds that iTOW implies; RTKLIB's solution (made from
    # RAWX) has its epochs 0.25 ms earlier at most.
    f = walk_ubx.fixes
    assert len(f) == 536 and set(f.q) <= {1, 2}
    np.testing.assert_allclose(f.t_abs % 604800, p["itow_ms"] * 1e-3, atol=1e-3)
    pos = rtklib_pos.read(POS_FILE, GEOID_M)
    assert np.max(np.abs(f.t_abs - pos.t_abs)) < 1e-3
    # The .pos heights are above the geoid (its height column is NAV-PVT's hMSL to the mm where both are fixed).
    both = (pos.q == 1) & (f.q == 1)
    assert both.sum() > 300
    assert np.median(np.abs(pos.llh()[both, 2] - f.llh()[both, 2])) < 0.01
    llh = f.llh()
    np.testing.assert_allclose(np.degrees(llh[:, 0]), p["lat"] * 1e-7, atol=1e-10)
    np.testing.assert_allclose(f.sigma_ned_m[:, 2], p["v_acc_mm"] * 1e-3)
    np.testing.assert_allclose(np.hypot(f.sigma_ned_m[:, 0], f.sigma_ned_m[:, 1]), p["h_acc_mm"] * 1e-3)

    sfrbx = [m for m in pyubx2_messages if m.identity == "RXM-SFRBX" and m.gnssId == 0 and m.sigId == 0]
    assert walk_ubx.subframes["GPS L1 C/A subframes"] == len(sfrbx) == 80
    assert walk_ubx.subframes["parity failures (subframe dropped)"] == 0


def test_gps_l1_pseudoranges_are_the_valid_l1_ca_rows(walk_ubx):
    r = walk_ubx.rawx
    sel = (r["gnss"] == 0) & (r["sig"] == 0) & ((r["trk"] & 1) == 1)
    both = walk_ubx.pseudoranges
    pr = both.select(both.prn <= 32)
    assert len(pr) == sel.sum() == 3842
    np.testing.assert_array_equal(pr.pr_m, r["pr_m"][sel])
    assert np.all((pr.pr_m > 1.9e7) & (pr.pr_m < 2.6e7))
    assert len(pr.epochs()) == 536
    assert np.all(pr.doppler_hz == r["doppler_hz"][sel]) and np.allclose(pr.lock_s, r["lock_ms"][sel] / 1000)
    gal = walk_ubx.signal(ubx.GNSS_GALILEO, 0)  # E1 C
    assert len(gal) == ((r["gnss"] == 2) & (r["sig"] == 0) & ((r["trk"] & 1) == 1)).sum() > 0
    # Galileo E1 C in the same table under the core's ids (E01 = 33), after each epoch's GPS rows.
    assert len(both) == len(pr) + len(gal) and set(both.prn[both.prn > 32]) == set(gal.prn + 32)
    for _t, prns, _ in both.epochs():
        assert prns == sorted(prns, key=lambda i: i > 32)
    tab = pr.table(WEEK * 604800.0)
    assert tab.shape == (3842, 6) and np.all(np.diff(tab[:, 0]) >= 0)
    np.testing.assert_array_equal(tab[:, 5], r["doppler_hz"][sel])  # the Doppler column, as RAWX has it


def test_rawx_doppler_is_the_rtk_velocity_seen_along_each_line_of_sight(walk_ubx):
    """RAWX's Doppler against RTKLIB's velocity at the fixed epochs: -wavelength x Doppler + c x the satellite's
    clock drift - u . (v_sat - v_rtk) - the Sagnac term's rate leaves the receiver's clock drift, common to every
    satellite of an epoch. The satellite's velocity and clock drift are differences of the core's orbit over
    +-0.5 s here. A wrong sign, unit or satellite velocity would leave hundreds of m/s between satellites."""
    c, om = 299792458.0, 7.2921151467e-5
    lam = c / 1575.42e6  # GPS L1 and Galileo E1
    ref = rtklib_pos.read(POS_FILE, GEOID_M)
    pr, store = walk_ubx.pseudoranges, walk_ubx.navigation.store()
    b = pr.epoch_starts()
    spread, drift, per_sat = [], [], {}
    for i, j in zip(b[:-1], b[1:]):
        t = pr.t_abs[i]
        k = np.flatnonzero(np.abs(ref.t_abs - t) < 0.01)
        if not len(k) or ref.q[k[0]] != 1:
            continue
        r, llh = ref.r_ecef[k[0]], ref.llh()[k[0]]
        v = c_en(llh[0], llh[1]) @ ref.v_ned_mps[k[0]]
        res = {}
        for n in range(i, j):
            eph = store.select(int(pr.prn[n]), t)
            if eph is None:
                continue
            tx = t - pr.pr_m[n] / c
            (s0, _), (sa, ca), (sb, cb) = (_core.gnss.sat_state(eph, tx + h) for h in (0.0, -0.5, 0.5))
            v_s, s_drift = np.subtract(sb, sa), cb - ca
            u = (s0 - r) / np.linalg.norm(s0 - r)
            if np.degrees(np.arcsin(u @ r / np.linalg.norm(r))) < 15.0:
                continue
            sagnac_rate = om / c * (v_s[0] * r[1] + s0[0] * v[1] - v_s[1] * r[0] - s0[1] * v[0])
            res[int(pr.prn[n])] = -lam * pr.doppler_hz[n] + c * s_drift - u @ (v_s - v) - sagnac_rate
        if len(res) >= 5:
            med = np.median(list(res.values()))
            drift.append((t, med))
            spread += [x - med for x in res.values()]
            for p, x in res.items():
                per_sat.setdefault(p, []).append(x - med)
    spread, drift = np.array(spread), np.array(drift)
    bias = {p: np.mean(x) for p, x in per_sat.items() if len(x) > 50}
    print(f"\nDoppler less the RTK velocity about each epoch's median: RMS {np.sqrt(np.mean(spread ** 2)):.3f} m/s "
          f"over {len(drift)} epochs; per-satellite means {np.round(list(bias.values()), 3)} m/s; clock drift "
          f"{drift[0, 1]:.1f} to {drift[-1, 1]:.1f} m/s")
    assert len(drift) > 300 and len(bias) >= 8
    # Measured: 0.20 m/s RMS (0.07 at 81 deg, 0.45 for the lowest satellite: a hand-held antenna), per-satellite
    # means within 0.06 m/s: no satellite's orbit or clock rate is off.
    assert np.sqrt(np.mean(spread ** 2)) < 0.3 and max(abs(x) for x in bias.values()) < 0.1
    # The drift is the receiver's oscillator: tens of m/s (1e-7), the same whichever satellites are in view, and
    # as the pseudoranges' own clock changes. It ramps by about 0.12 m/s each second over the walk.
    slope = np.polyfit(drift[:, 0] - drift[0, 0], drift[:, 1], 1)[0]
    assert 20.0 < -drift[:, 1].mean() < 200.0 and 0.05 < abs(slope) < 0.3


def range_residual(store, prn: int, t: float, pr: float, r_rx, llh) -> float | None:
    """A pseudorange minus its model at a known receiver position: range + Sagnac - satellite clock + group delay +
    troposphere, the satellite at its transmission time. Left: the receiver clock and the ionosphere (metres)."""
    eph = store.select(prn, t)
    if eph is None:
        return None
    tx = t - pr / 299792458.0
    for _ in range(2):
        r_sat, clk = _core.gnss.sat_state(eph, tx)
        tx = t - pr / 299792458.0 - clk
    r_sat, clk = _core.gnss.sat_state(eph, tx)
    _, el = _core.gnss.az_el(r_rx, r_sat)
    model = np.linalg.norm(r_sat - r_rx) + _core.gnss.sagnac_m(r_sat, r_rx) \
        - 299792458.0 * (clk - eph.tgd_s) + _core.gnss.saastamoinen_m(llh, el)
    return pr - model


def test_sfrbx_ephemerides_give_spp_within_metres_of_the_rtk_reference(walk_ubx):
    """End-to-end check of RAWX + SFRBX: ephemerides from the subframes through the core's decoder, SPP on the
    L1 C/A pseudoranges, against RTKLIB's RTK solution."""
    nav = walk_ubx.navigation
    assert [i for i in nav.prns() if i <= 32] == [10, 23, 27, 32]  # only four GPS satellites complete in 134 s
    assert all(e.week == WEEK and e.health == 0 for e in nav.ephemerides if e.prn <= 32)
    assert nav.alpha == []  # no subframe 4 page 18 in 134 s: no Klobuchar
    eps = walk_ubx.pseudoranges.select(walk_ubx.pseudoranges.prn <= 32).epochs()
    ep = spp.Epochs([e[0] for e in eps], [e[1] for e in eps], [e[2] for e in eps], nav.store())
    run = spp.solve(ep, 10.0)
    assert run.ok.sum() >= 500
    ref = rtklib_pos.read(POS_FILE, GEOID_M)
    k = np.searchsorted(ref.t_abs, run.t_abs[run.ok] - 0.01)
    assert np.max(np.abs(ref.t_abs[k] - run.t_abs[run.ok])) < 2e-3  # RTKLIB rounds to the ms
    llh = ref.llh()[k]
    e = np.einsum("nji,nj->ni", c_en(llh[:, 0], llh[:, 1]), run.r_ecef[run.ok] - ref.r_ecef[k])
    h = np.hypot(e[:, 0], e[:, 1])
    print(f"walk SPP (4 satellites, no ionosphere model): mean NED {e.mean(0).round(2)} m, "
          f"median horizontal {np.median(h):.2f} m, HDOP {np.nanmean(run.dops[:, 2]):.2f}")
    # Four satellites, HDOP about 2.4 and no ionosphere model (several metres of L1 delay, which raises the height,
    # about +5.9 m on the GEONET pair): metres, not km.
    assert np.median(h) < 12.0 and 0.0 < -np.median(e[:, 2]) < 12.0

    # Each satellite on its own: at the RTK position, range + Sagnac - satellite clock + TGD + troposphere leaves
    # the receiver clock, common to all satellites, and the ionosphere (metres). A wrong orbit would stand out.
    t, prns, prs = eps[0]
    r_rx = ref.r_ecef[0]
    llh0 = ref.llh()[0]
    store = nav.store()
    res = {prn: range_residual(store, prn, t, pr, r_rx, llh0) for prn, pr in zip(prns, prs)}
    res = {prn: v for prn, v in res.items() if v is not None}
    assert sorted(res) == [10, 23, 27, 32]
    spread = np.ptp(list(res.values()))
    print("per-satellite residuals minus their mean (m):", {p: round(v - np.mean(list(res.values())), 2)
                                                           for p, v in res.items()})
    # Metres (the ionosphere differs between elevations of 32 and 65 deg; the handheld antenna's multipath); an
    # orbit from a wrong subframe set or a wrong week would be off by kilometres.
    assert spread < 20.0


def test_crc24q_gives_its_published_check_value():
    from gpsins.formats.galileo_inav import crc24q
    assert crc24q(b"123456789") == 0xCDE703  # the CRC catalogue's check value of CRC-24Q (CRC-24/LTE-A)
    assert crc24q(b"") == 0


def test_galileo_inav_pages_give_ephemerides_whose_ranges_fit_the_rtk_reference(walk_ubx):
    """Every E1-B page of the walk passes its CRC (the page layout is right bit for bit); the orbits decoded from
    word types 1-5 put each Galileo satellite within metres of where its pseudorange says, at the RTK position,
    once the receiver's clock (with its Galileo offset) is taken out."""
    st = walk_ubx.subframes
    assert st["Galileo I/NAV pages"] == 396 and not any("page dropped" in k for k in st)
    nav = walk_ubx.navigation
    gal = [e for e in nav.ephemerides if e.prn > 32]
    assert sorted(ubx.sat_name(e.prn) for e in gal) == ["E07", "E08", "E13", "E14", "E26", "E29", "E33"]
    assert sum(e.health == 0 for e in gal) == 6
    for e in gal:
        assert e.week == WEEK and e.iode == e.iodc and abs(e.tgd_s) < 2e-8  # BGD E1/E5b: nanoseconds
        if ubx.sat_name(e.prn) == "E14":
            # GSAT0201, left in an eccentric orbit by its launcher in 2014 (about 17 200 x 26 000 km at 50 deg);
            # it broadcasts signal health 1: not to be used.
            assert e.e == pytest.approx(0.16, abs=0.01) and np.degrees(e.i0) == pytest.approx(49.5, abs=1.0)
            assert e.health == 2 and nav.store().select(e.prn, e.week * 604800.0 + e.toe_s) is None
        else:  # 29 600 km circular orbits at 56 deg, healthy
            assert 5438.0 < e.sqrt_a < 5442.0 and e.e < 0.01 and e.health == 0
            assert np.degrees(e.i0) == pytest.approx(56.0, abs=2.0)
    ref = rtklib_pos.read(POS_FILE, GEOID_M)
    pr = walk_ubx.pseudoranges
    store = nav.store()
    res = {}
    for t, prns, prs in pr.epochs()[::40]:
        k = np.searchsorted(ref.t_abs, t - 0.01)
        if k >= len(ref.t_abs) or abs(ref.t_abs[k] - t) > 0.01:
            continue
        r_rx, llh = ref.r_ecef[k], ref.llh()[k]
        row = {prn: range_residual(store, prn, t, p, r_rx, llh) for prn, p in zip(prns, prs)}
        g = [v for i, v in row.items() if i <= 32 and v is not None]
        e = [v for i, v in row.items() if i > 32 and v is not None]
        if len(g) >= 3 and len(e) >= 3:
            res[t] = (np.array(g) - np.median(g), np.array(e) - np.median(e), np.median(e) - np.median(g))
    assert len(res) >= 10
    spread_e = np.concatenate([x[1] for x in res.values()])
    isb = np.array([x[2] for x in res.values()])
    print(f"Galileo residuals about their epoch's median: RMS {np.sqrt(np.mean(spread_e ** 2)):.2f} m; "
          f"Galileo minus GPS median {isb.mean():.2f} +- {isb.std():.2f} m")
    # Metres (no Klobuchar in 134 s, multipath at 16-26 deg on E08 and E13), as GPS's own; a wrong field would put
    # a satellite kilometres off. The offset itself: about -1.5 m (GGTO and the receiver's bias).
    assert np.sqrt(np.mean(spread_e ** 2)) < 8.0 and np.percentile(np.abs(spread_e), 95) < 15.0
    assert isb.std() < 5.0  # the receiver's Galileo offset is a constant, not noise


def test_lnav_parity_detects_every_single_bit_error(walk_ubx):
    data = UBX_FILE.read_bytes()
    frames, _ = ubx.split_frames(data)
    import struct
    for _, cls, mid, start, _length in frames:
        if (cls, mid) == (0x02, 0x13) and data[start] == 0 and data[start + 2] == 0:
            words = [w & 0x3FFFFFFF for w in struct.unpack_from("<10I", data, start + 8)]
            break
    prev = 0
    for w in words:
        d29 = ((prev >> 1) ^ prev) & 1
        assert ubx.lnav_parity_ok(w, d29, 0)
        for bit in range(30):
            assert not ubx.lnav_parity_ok(w ^ (1 << bit), d29, 0)
        prev = w


def test_klobuchar_from_subframe_4_page_18():
    # Alpha and beta as broadcast (integers times their scale factors), packed by hand after IS-GPS-200.
    a = [12, -3, -60, 119]  # 2^-30, 2^-27, 2^-24, 2^-24
    b = [98, -2, -128, 4]  # 2^11, 2^14, 2^16, 2^16
    u8 = [x & 0xFF for x in a + b]
    w3 = (0b01 << 22) | (56 << 16) | (u8[0] << 8) | u8[1]
    w4 = (u8[2] << 16) | (u8[3] << 8) | u8[4]
    w5 = (u8[5] << 16) | (u8[6] << 8) | u8[7]
    alpha, beta = ubx.klobuchar_from_page18([w3, w4, w5, 0, 0, 0, 0, 0])
    assert alpha == [12 * 2.0 ** -30, -3 * 2.0 ** -27, -60 * 2.0 ** -24, 119 * 2.0 ** -24]
    assert beta == [98 * 2048.0, -2 * 16384.0, -128 * 65536.0, 4 * 65536.0]


def test_damaged_ubx_keeps_every_good_frame(walk_ubx):
    data = bytearray(UBX_FILE.read_bytes())
    frames, _ = ubx.split_frames(bytes(data))
    rawx = [f for f in frames if (f[1], f[2]) == (0x02, 0x15)]
    victim = rawx[100]
    data[victim[3] + 20] ^= 0x10  # one bit of a pseudorange: checksum fails
    cut = frames[-1][0] + 20  # into the last frame
    garbage = b"\x00\xb5\x62\x02\x15\xff\xff junk"
    damaged = bytes(data[:frames[10][0]]) + garbage + bytes(data[frames[10][0]:cut])  # garbage, truncated end
    u = ubx.parse(damaged, "walk-damaged.ubx")
    last = frames[-1]
    assert u.counts["RXM-RAWX"] == 536 - 1
    lost_at_end = sum(1 for f in frames if f[0] + f[4] + 8 > cut)
    assert lost_at_end == 1
    assert sum(u.counts[k] for k in ("RXM-RAWX", "RXM-SFRBX", "NAV-PVT")) == 3400 - 1 - lost_at_end
    offsets = [d.offset for d in u.damage]
    assert offsets[0] == frames[10][0]  # the garbage, at its own offset
    assert victim[0] + len(garbage) in offsets  # the damaged RAWX
    assert "bad checksum of class 0x02 id 0x15" in [d.reason for d in u.damage]
    assert u.damage[-1].offset == last[0] + len(garbage)
    assert "truncated" in u.damage[-1].reason
    assert "offset" in u.damage_summary() and "walk-damaged.ubx" in u.damage_summary()
    # Every measurement of the other 535 epochs is as before.
    keep = walk_ubx.rawx_t_abs != np.unique(walk_ubx.rawx_t_abs)[100]
    np.testing.assert_array_equal(u.rawx, walk_ubx.rawx[keep])


def test_not_ubx_is_one_clear_error(tmp_path):
    p = tmp_path / "x.ubx"
    p.write_bytes(b"$GPGGA,nothing here\r\n" * 10)
    with pytest.raises(ReaderError, match=r"x\.ubx \(offset 0\): no UBX frame"):
        ubx.read(p)
    with pytest.raises(ReaderError, match="missing.ubx"):
        ubx.read(tmp_path / "missing.ubx")


# --- RTKLIB .pos ----------------------------------------------------------------------------------------------

def test_rtklib_pos_columns_as_printed():
    f = rtklib_pos.read(POS_FILE)
    lines = [x.split() for x in POS_FILE.read_text().splitlines() if not x.startswith("%")]
    assert len(f) == len(lines) == 536
    assert (f.q == 1).sum() == 349 and (f.q == 2).sum() == 187  # the README's counts
    for k in (0, 200, 535):
        tok = lines[k]
        y, mo, d = (int(x) for x in tok[0].split("/"))
        h, mi, s = tok[1].split(":")
        assert f.t_abs[k] == pytest.approx(gps_seconds(y, mo, d, int(h), int(mi), float(s)), abs=1e-6)
        llh = f.llh()[k]
        assert np.degrees(llh[0]) == pytest.approx(float(tok[2]), abs=1e-10)
        assert np.degrees(llh[1]) == pytest.approx(float(tok[3]), abs=1e-10)
        assert llh[2] == pytest.approx(float(tok[4]), abs=1e-6)
        assert f.q[k] == int(float(tok[5])) and f.ns[k] == int(float(tok[6]))
        np.testing.assert_allclose(f.sigma_ned_m[k], [float(x) for x in tok[7:10]])
        np.testing.assert_allclose(f.v_ned_mps[k], [float(tok[15]), float(tok[16]), -float(tok[17])])
        np.testing.assert_allclose(f.sigma_v_ned_mps[k], [float(x) for x in tok[18:21]])
    assert f.t_abs[0] // 604800 == WEEK


POS_ECEF = ("% program   : hand-written\n"
            "%  GPST                      x-ecef(m)      y-ecef(m)      z-ecef(m)   Q  ns"
            "   sdx(m)   sdy(m)   sdz(m)  sdxy(m)  sdyz(m)  sdzx(m) age(s)  ratio\n"
            "2381 408639.750   -1283585.1234  -4726890.9876   4079493.5000   5  9"
            "   3.0000   0.0000   0.0000   0.0000   0.0000   0.0000   0.00    0.0\n"
            "2381 408640.000   -1283585.2234  -4726891.0876   4079493.4000   2  9"
            "   0.0000   0.0000   0.0000   0.0000   0.0000   0.0000   0.00    0.0\n")


def test_rtklib_pos_ecef_week_seconds_and_errors(tmp_path):
    p = tmp_path / "e.pos"
    p.write_text(POS_ECEF)
    f = rtklib_pos.read(p)
    np.testing.assert_allclose(f.t_abs, [WEEK * 604800 + 408639.75, WEEK * 604800 + 408640.0])
    np.testing.assert_allclose(f.r_ecef[1], [-1283585.2234, -4726891.0876, 4079493.4])
    np.testing.assert_array_equal(f.q, [5, 2])
    # sdx only: its variance spread over NED by the rotation (north^2 + east^2 + down^2 = 9).
    assert np.sum(f.sigma_ned_m[0] ** 2) == pytest.approx(9.0)
    assert np.all(f.sigma_ned_m[1] == 0.0)  # zero sigmas are kept as they are: floors are the filter's business
    assert f.v_ned_mps is None
    p.write_text(POS_ECEF.replace("4079493.4000", "4079493.4x00"))
    with pytest.raises(ReaderError, match=r"e\.pos:4: z-ecef\(m\): bad value"):
        rtklib_pos.read(p)
    p.write_text("2381 408639.750 1 2 3 5 9\n")
    with pytest.raises(ReaderError, match="no column header"):
        rtklib_pos.read(p)


# --- RINEX 2 and 3 ---------------------------------------------------------------------------------------------

def _fmt_d(x: float) -> str:
    """A D19.12 number as RINEX writes it."""
    return f"{x:19.12E}".replace("E", "D")


def write_rinex3_nav(path: Path, nav: common.Navigation) -> None:
    lines = [f"{'3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}{'G: GPS':<20}RINEX VERSION / TYPE",
             "GPSA " + "".join(f"{x:12.4E}" for x in nav.alpha) + " " * 7 + "IONOSPHERIC CORR",
             "GPSB " + "".join(f"{x:12.4E}" for x in nav.beta) + " " * 7 + "IONOSPHERIC CORR",
             f"{'':60}END OF HEADER"]
    # A GLONASS record first: a mixed file's other systems must be skipped by their length.
    lines += ["R01 2005 04 02 00 15 00" + _fmt_d(1e-5) * 3] + ["    " + _fmt_d(0.0) * 4] * 3
    ura_m = rinex.URA_TABLE_M
    for e in nav.ephemerides:
        toc = gpstime.GPS_EPOCH.timestamp() + e.week * 604800 + e.toc_s
        import datetime as dt
        c = dt.datetime.fromtimestamp(toc, dt.timezone.utc)
        lines.append(f"G{e.prn:02d} {c.year:4d} {c.month:02d} {c.day:02d} {c.hour:02d} {c.minute:02d} {c.second:02d}"
                     + _fmt_d(e.af0) + _fmt_d(e.af1) + _fmt_d(e.af2))
        rows = [(e.iode, e.crs, e.delta_n, e.m0), (e.cuc, e.e, e.cus, e.sqrt_a), (e.toe_s, e.cic, e.omega0, e.cis),
                (e.i0, e.crc, e.omega, e.omega_dot), (e.idot, 1.0, e.week, 0.0),
                (ura_m[e.ura_index], e.health, e.tgd_s, e.iodc), (e.toe_s, 4.0 if e.fit_interval_long else 0.0)]
        lines += ["    " + "".join(_fmt_d(v) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")


def write_rinex3_obs(path: Path, obs: rinex.ObsFile) -> None:
    """The GEONET epochs as RINEX 3, with a Doppler column (-1000.5 + PRN Hz) and a Galileo satellite added to every
    epoch (to be skipped)."""
    v3 = {"C1": "C1C", "P1": "C1W", "L1": "L1C", "D1": "D1C", "S1": "S1C", "P2": "C2W", "L2": "L2W", "C2": "C2X",
          "S2": "S2W", "D2": "D2W"}
    types = [v3.get(t, t) for t in obs.types] + ["D1C"]
    x, y, z = obs.approx_xyz
    lines = [f"{'3.04':>9}{'':11}{'OBSERVATION DATA':<20}{'M: Mixed':<20}RINEX VERSION / TYPE",
             f"{x:14.4f}{y:14.4f}{z:14.4f}{'':18}APPROX POSITION XYZ"]
    head = f"G  {len(types):3d}" + "".join(f" {t}" for t in types[:13])
    lines.append(f"{head:<60}SYS / # / OBS TYPES")
    rest = types[13:]
    while rest:
        line = "      " + "".join(f" {t}" for t in rest[:13])
        lines.append(f"{line:<60}SYS / # / OBS TYPES")
        rest = rest[13:]
    lines.append(f"{'E    1 C1C':<60}SYS / # / OBS TYPES")
    lines.append(f"{'':60}END OF HEADER")
    import datetime as dt
    for t, prns, values in obs.epochs:
        c = gpstime.GPS_EPOCH + dt.timedelta(seconds=t)
        sec = c.second + c.microsecond * 1e-6
        lines.append(f"> {c.year:4d} {c.month:02d} {c.day:02d} {c.hour:02d} {c.minute:02d}{sec:11.7f}"
                     f"  0{len(prns) + 1:3d}")
        for prn, v in zip(prns, values):
            v = list(v) + [-1000.5 + prn]
            lines.append(f"G{prn:02d}" + "".join("".ljust(16) if np.isnan(a) else f"{a:14.3f}  " for a in v).rstrip())
        lines.append("E11  22000000.000")
    path.write_text("\n".join(lines) + "\n")


def test_rinex2_geonet_epochs(shared_data):
    obs = rinex.read_obs(shared_data / "07590920.05o")
    assert len(obs.epochs) == 120 and obs.version == pytest.approx(2.10)
    assert obs.epochs[0][0] == gps_seconds(2005, 4, 2, 0, 0, 0.0)
    assert obs.epochs[-1][0] == gps_seconds(2005, 4, 2, 0, 59, 30.005)  # as printed
    np.testing.assert_allclose(obs.approx_xyz, [-3976219.5082, 3382372.5671, 3652512.9849])
    l1 = obs.gps_l1()
    assert len(l1.epochs()) == 120
    # The first epoch's first C1 as printed in the file.
    text = (shared_data / "07590920.05o").read_text().splitlines()
    i = next(k for k, x in enumerate(text) if "END OF HEADER" in x) + 1
    sat = text[i][32:35]
    rows_per_sat = (len(obs.types) + 4) // 5
    c1 = obs.types.index("C1")
    n_sat_lines = 1 + (int(text[i][29:32]) - 1) // 12
    first = "".join(text[i + n_sat_lines + r].ljust(80) for r in range(rows_per_sat))
    assert l1.prn[0] == int(sat[1:]) and l1.pr_m[0] == float(first[16 * c1:16 * c1 + 14])
    assert np.isnan(l1.doppler_hz).all() == ("D1" not in obs.types)


def test_rinex3_reads_the_same_values_as_rinex2(shared_data, tmp_path):
    nav2 = rinex.read_nav(shared_data / "07590920.05n")
    obs2 = rinex.read_obs(shared_data / "07590920.05o")
    write_rinex3_nav(tmp_path / "g.rnx", nav2)
    write_rinex3_obs(tmp_path / "o.rnx", obs2)
    nav3 = rinex.read_nav(tmp_path / "g.rnx")
    obs3 = rinex.read_obs(tmp_path / "o.rnx")
    assert obs3.version == pytest.approx(3.04) and "C1C" in obs3.types and "C1" not in obs3.types
    assert len(nav3.ephemerides) == len(nav2.ephemerides) > 0
    assert nav3.alpha == pytest.approx(nav2.alpha, rel=1e-4) and nav3.beta == pytest.approx(nav2.beta, rel=1e-4)
    for a, b in zip(nav2.ephemerides, nav3.ephemerides):
        for name in ("prn", "week", "toe_s", "toc_s", "sqrt_a", "e", "i0", "omega0", "omega", "m0", "delta_n", "idot",
                     "omega_dot", "cuc", "cus", "crc", "crs", "cic", "cis", "af0", "af1", "af2", "tgd_s", "iode",
                     "iodc", "health", "ura_index", "fit_interval_long"):
            assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-11, abs=1e-300), name
    assert len(obs3.epochs) == len(obs2.epochs)
    l2, l3 = obs2.gps_l1(), obs3.gps_l1()
    np.testing.assert_array_equal(l3.t_abs, l2.t_abs)
    np.testing.assert_array_equal(l3.prn, l2.prn)
    np.testing.assert_allclose(l3.pr_m, l2.pr_m, atol=1e-3)
    np.testing.assert_array_equal(l3.doppler_hz, -1000.5 + l3.prn)
    assert np.isnan(l2.doppler_hz).all()  # the RINEX 2 file has no D1
    # The same SPP through spp.from_rinex (which asks for "C1": found as C1C).
    r2 = spp.solve(spp.from_rinex(shared_data / "07590920.05o", shared_data / "07590920.05n"), 15.0)
    r3 = spp.solve(spp.from_rinex(tmp_path / "o.rnx", tmp_path / "g.rnx"), 15.0)
    assert r3.ok.sum() == r2.ok.sum() >= 110
    assert np.nanmax(np.abs(r3.r_ecef - r2.r_ecef)) < 1e-3


def test_rinex_errors_name_file_and_line(shared_data, tmp_path):
    text = (shared_data / "07590920.05o").read_text().splitlines()
    i = next(k for k, x in enumerate(text) if "END OF HEADER" in x) + 3
    text[i] = text[i][:5] + "abc.def" + text[i][12:]
    p = tmp_path / "bad.05o"
    p.write_text("\n".join(text) + "\n")
    with pytest.raises(rinex.RinexError, match=rf"bad\.05o:{i + 1}"):
        rinex.read_obs(p)
    p.write_text("not rinex\n")
    with pytest.raises(ReaderError, match=r"bad\.05o:1"):
        rinex.read_obs(p)


# --- KF-GINS --------------------------------------------------------------------------------------------------

def test_kfgins_imu_and_gnss_text(tmp_path):
    rng = np.random.default_rng(1)
    sow = 604795.0 + np.arange(1000) * 0.01  # crosses the week end
    dth, dv = rng.normal(0, 1e-4, (1000, 3)), rng.normal(0, 1e-2, (1000, 3))
    (tmp_path / "imu.txt").write_text("".join(
        f"{t:.3f} {a[0]:.12e} {a[1]:.12e} {a[2]:.12e} {b[0]:.12e} {b[1]:.12e} {b[2]:.12e}\n"
        for t, a, b in zip(sow % 604800, dth, dv)))
    imu = kfgins.read_imu(tmp_path / "imu.txt", 2100)
    np.testing.assert_allclose(imu.t_abs, 2100 * 604800 + sow, atol=1e-6)
    np.testing.assert_allclose(imu.dtheta_rad, dth, rtol=1e-11)
    np.testing.assert_allclose(imu.dv_mps, dv, rtol=1e-11)
    (tmp_path / "gnss.txt").write_text("# sow lat lon h sn se sd\n"
                                       "100.0 30.444 114.471 20.5 0.005 0.004 0.008\n"
                                       "101.0 30.445 114.472 21.5 0.0 0.0 0.0\n")
    g = kfgins.read_gnss(tmp_path / "gnss.txt", 2100)
    assert np.degrees(g.llh()[1, :2]) == pytest.approx([30.445, 114.472], abs=1e-10)
    assert g.llh()[0, 2] == pytest.approx(20.5, abs=1e-6)
    np.testing.assert_array_equal(g.sigma_ned_m[0], [0.005, 0.004, 0.008])
    (tmp_path / "gnss.txt").write_text("100.0 30.444 114.471 20.5 0.005 0.004 0.008\n101.0 30.445 114.472\n")
    with pytest.raises(ReaderError, match=r"gnss\.txt:2"):
        kfgins.read_gnss(tmp_path / "gnss.txt", 2100)


# --- IMU CSV --------------------------------------------------------------------------------------------------

def test_imu_csv_rates_become_trapezoid_increments_in_si_units(tmp_path):
    t = np.array([float(f"{x:.4f}") for x in 1.7e9 + np.array([0.0, 0.006, 0.015, 0.021])])  # uneven steps
    acc_g = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.2, -0.1, 0.9], [0.2, -0.1, 0.9]])
    gyr_dps = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [3.0, 0.0, -3.0], [0.0, 0.0, 0.0]])
    rows = ["time,unused,ax,ay,az,gx,gy,gz,extra"]
    rows += [f"{a:.4f},9,{b[0]},{b[1]},{b[2]},{c[0]},{c[1]},{c[2]},7" for a, b, c in zip(t, acc_g, gyr_dps)]
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(rows) + "\n")
    d = imu_csv.read(p, ["t", "-", "ax", "ay", "az", "gx", "gy", "gz"], "gpst_unix", "g", "deg/s")
    assert len(d) == 3
    np.testing.assert_allclose(d.t_abs, t[1:] - 315964800.0)
    # Hand-computed: interval 2 (9 ms, as near as float64 holds it at 1.7e9 s), accel mean (0.15, -0.05, 0.95) g,
    # gyro mean (2, 1, 0) deg/s.
    dt = np.diff(t)
    assert dt[1] == pytest.approx(0.009, abs=1e-6)
    np.testing.assert_allclose(d.dv_mps[1], np.array([0.15, -0.05, 0.95]) * 9.80665 * dt[1], rtol=1e-12)
    np.testing.assert_allclose(d.dtheta_rad[1], np.radians([2.0, 1.0, 0.0]) * dt[1], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(d.dtheta_rad[0], np.radians([1.0, 2.0, 3.0]) * dt[0], rtol=1e-12)
    # Increments are taken as they are, one per row.
    d2 = imu_csv.read(p, ["t", "-", "ax", "ay", "az", "gx", "gy", "gz"], "gpst_unix", "m/s", "deg")
    assert len(d2) == 4
    np.testing.assert_allclose(d2.dtheta_rad[2], np.radians([3.0, 0.0, -3.0]))
    np.testing.assert_allclose(d2.dv_mps, acc_g)


def test_imu_csv_time_scales_glitches_and_bad_values(tmp_path):
    p = tmp_path / "imu.txt"
    p.write_text("604799.99 0 0 1 0 0 0\n604800.00 0 0 1 0 0 0\n0.01 0 0 1 0 0 0\n0.005 0 0 1 0 0 0\n"
                 "0.02 0 0 1 0 0 0\n")
    cols = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    d = imu_csv.read(p, cols, "gps_sow", "m/s", "rad", week=2000)
    # The week rolls over at the drop; the stamp that goes back (0.005 after 0.01) is dropped and counted.
    np.testing.assert_allclose(d.t_abs - 2000 * 604800.0, [604799.99, 604800.0, 604800.01, 604800.02])
    assert d.skipped["IMU samples whose time does not increase"] == 1
    with pytest.raises(ReaderError, match="week"):
        imu_csv.read(p, cols, "gps_sow", "m/s", "rad")
    p.write_text("1 0 0 1 0 0 0\n2 0 0 1 0 0 0\n3 0 0 x 0 0 0\n")
    with pytest.raises(ReaderError, match=r"imu\.txt:3: column 4 \(az\): 'x' is not a number"):
        imu_csv.read(p, cols, "gps_abs")
    with pytest.raises(ReaderError, match="accel_unit"):
        imu_csv.read(p, cols, "gps_abs", "furlong")
    with pytest.raises(ReaderError, match="columns lack gz"):
        imu_csv.read(p, cols[:-1], "gps_abs")


def test_walk_csv_first_increment_by_hand():
    p = WALK / "imu_1730_sf.csv"
    first = [[float(x) for x in line.split(",")] for line in p.read_text().splitlines()[:2]]
    d = imu_csv.read(p, ["t", "ax", "ay", "az", "gx", "gy", "gz"], "gpst_unix", "g", "rad/s")
    assert len(d) == 20454  # 20,455 rows (README)
    dt = first[1][0] - first[0][0]
    assert d.t_abs[0] == pytest.approx(first[1][0] - UNIX_TO_GPS_S, abs=1e-6)
    np.testing.assert_allclose(d.dv_mps[0], [(a + b) / 2 * 9.80665 * dt for a, b in zip(first[0][1:4], first[1][1:4])],
                               rtol=1e-6)
    assert 140 < len(d) / (d.t_abs[-1] - d.t_abs[0]) < 160  # about 152 Hz


def test_rtklib_pos_utc_times_and_dms_angles(tmp_path):
    # The walk's first epoch written as RTKLIB does with "time = UTC" and "lat/lon format = ddd mm ss":
    # 17:30:39.749 GPST is 17:30:21.749 UTC (18 leap seconds); 40.0966916 deg = 40 05 48.08976,
    # -105.1471665 deg = -105 08 49.79940.
    p = tmp_path / "u.pos"
    p.write_text("%  UTC                   latitude(d'\")   longitude(d'\")  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)\n"  # noqa: E501
                 "2025/08/28 17:30:21.749   40 05 48.08976 -105 08 49.79940  1580.0480   1  25   0.0099   0.0099   0.0100\n")  # noqa: E501
    f = rtklib_pos.read(p)
    ref = rtklib_pos.read(POS_FILE, GEOID_M)
    assert f.t_abs[0] == pytest.approx(ref.t_abs[0], abs=1e-6)
    np.testing.assert_allclose(np.degrees(f.llh()[0, :2]), np.degrees(ref.llh()[0, :2]), atol=1e-9)
    assert f.llh()[0, 2] == pytest.approx(ref.llh()[0, 2], abs=1e-6)
    np.testing.assert_allclose(f.sigma_ned_m[0], [0.0099, 0.0099, 0.01])


def test_gzipped_files_read_the_same(shared_data, tmp_path):
    import gzip
    for src in (shared_data / "07590920.05o", shared_data / "07590920.05n", UBX_FILE, WALK / "imu_1730_sf.csv"):
        (tmp_path / (src.name + ".gz")).write_bytes(gzip.compress(src.read_bytes()))
    a, b = rinex.read_obs(shared_data / "07590920.05o").gps_l1(), rinex.read_obs(tmp_path / "07590920.05o.gz").gps_l1()
    np.testing.assert_array_equal(a.pr_m, b.pr_m)
    assert len(rinex.read_nav(tmp_path / "07590920.05n.gz").ephemerides) == \
        len(rinex.read_nav(shared_data / "07590920.05n").ephemerides)
    assert ubx.read(tmp_path / "gnss_1730.ubx.gz").counts == ubx.read(UBX_FILE).counts
    cols = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    np.testing.assert_array_equal(imu_csv.read(tmp_path / "imu_1730_sf.csv.gz", cols, "gpst_unix", "g").dv_mps,
                                  imu_csv.read(WALK / "imu_1730_sf.csv", cols, "gpst_unix", "g").dv_mps)
    (tmp_path / "cut.ubx.gz").write_bytes(gzip.compress(UBX_FILE.read_bytes())[:5000])
    with pytest.raises(ReaderError, match=r"cut\.ubx\.gz"):
        ubx.read(tmp_path / "cut.ubx.gz")


# --- the table-at-once paths against the row-by-row ones they stand in for --------------------------------------

def _same_fields(a, b) -> bool:
    return all((getattr(a, k) is None and getattr(b, k) is None) or np.array_equal(getattr(a, k), getattr(b, k),
                                                                                    equal_nan=True)
               for k in vars(a) if isinstance(getattr(a, k), np.ndarray) or getattr(a, k) is None) and \
        a.skipped == b.skipped


def test_pos_read_at_once_equals_row_by_row(tmp_path, monkeypatch):
    """NumPy's parser over the whole table (rtklib_pos._table) against the per-row loop, which also names
    bad rows: calendar and week-second times, two-digit years, nan rows, RTKLIB's velocity columns."""
    walk = Path(__file__).parent / "data" / "walk_0827" / "gnss_1730_sf.pos"
    ecef = tmp_path / "e.pos"
    ecef.write_text(POS_ECEF)
    lines = walk.read_text().splitlines()
    data = [i for i, x in enumerate(lines) if x and not x.startswith("%")]
    lines[data[5]] = lines[data[5]].replace(lines[data[5]].split()[2], "nan", 1)  # a row to drop
    lines[data[7]] = "99/" + lines[data[7]][5:]  # 2099 by RINEX's two-digit rule
    edited = tmp_path / "w.pos"
    edited.write_text("\n".join(lines) + "\n")
    at_once = rtklib_pos._table
    used = []
    monkeypatch.setattr(rtklib_pos, "_table", lambda *a: used.append(at_once(*a)) or used[-1])
    fast = [rtklib_pos.read(p, g) for p, g in ((walk, -21.387), (ecef, None), (edited, -21.387))]
    assert all(u is not None for u in used) and len(used) == 3 and fast[2].skipped
    monkeypatch.setattr(rtklib_pos, "_table", lambda *a: None)
    slow = [rtklib_pos.read(p, g) for p, g in ((walk, -21.387), (ecef, None), (edited, -21.387))]
    assert all(_same_fields(a, b) for a, b in zip(fast, slow))
    monkeypatch.setattr(rtklib_pos, "_table", at_once)
    lines[data[9]] = lines[data[9]].replace(lines[data[9]].split()[0], "2019/02/30", 1)  # no such day
    edited.write_text("\n".join(lines) + "\n")
    with pytest.raises(ReaderError, match=rf"w\.pos:{data[9] + 1}: time: bad value"):
        rtklib_pos.read(edited, -21.387)


def test_imu_csv_read_in_pieces_equals_loadtxt(tmp_path, monkeypatch):
    """The table streams from the file in pieces cut at line ends (imu_csv.PIECE_BYTES): with pieces of a
    few lines, and gzipped, every value equals loadtxt's, the last line without its line end included,
    and more rows than the head's line length promised (short lines after long ones) still all arrive."""
    import gzip

    rng = np.random.default_rng(5)
    long_rows = [f"{1278016200.0 + 0.005 * k:.6f},{a:.12e},{b:.12e},{c:.12e},{d:.12e},{e:.12e},{f:.12e}"
                 for k, (a, b, c, d, e, f) in enumerate(rng.normal(size=(300, 6)))]
    short_rows = [f"{1278016202.0 + 0.005 * k:.3f},{a:.2f},{b:.2f},{c:.2f},{d:.2f},{e:.2f},{f:.2f}"
                  for k, (a, b, c, d, e, f) in enumerate(rng.normal(size=(5000, 6)))]
    text = "t,ax,ay,az,gx,gy,gz\n" + "\n".join(long_rows + short_rows)  # no line end at the end
    plain, packed = tmp_path / "imu.csv", tmp_path / "imu.csv.gz"
    plain.write_text(text)
    packed.write_bytes(gzip.compress(text.encode()))
    expected = np.loadtxt(text.splitlines()[1:], delimiter=",")
    monkeypatch.setattr(imu_csv, "PIECE_BYTES", 1000)
    for p in (plain, packed):
        got = imu_csv._read_table_fast(p, len("t,ax,ay,az,gx,gy,gz\n"), ",", list(range(7)), row_bytes=120.0)
        assert got is not None and got.shape == expected.shape
        np.testing.assert_array_equal(got, expected)


def test_imu_csv_read_by_pyarrow_equals_loadtxt(tmp_path, monkeypatch):
    """pyarrow's CSV reader (imu_csv._read_table_fast) against NumPy's loadtxt: CR LF ends, a header, nan and
    inf rows (dropped and counted), exponents, unused columns; a '#' comment goes to loadtxt."""
    rng = np.random.default_rng(3)
    rows = [f"{1278016200.0 + 0.005 * k:.6f},{a:.10e},{b:.6f},{c:.3f},{d:.8e},{e:.7f},{f:.9f},7,x"
            for k, (a, b, c, d, e, f) in enumerate(rng.normal(size=(2000, 6)))]
    rows[10] = rows[10].replace(rows[10].split(",")[2], "nan", 1)
    rows[20] = rows[20].replace(rows[20].split(",")[5], "-inf", 1)
    table = tmp_path / "imu.csv"
    table.write_bytes(("t,ax,ay,az,gx,gy,gz,n,s\r\n" + "\r\n".join(rows) + "\r\n").encode())
    commented = tmp_path / "c.csv"
    commented.write_text("t,ax,ay,az,gx,gy,gz\n" + "\n".join(",".join(r.split(",")[:7]) for r in rows[:50])
                         + "  # the last\n")
    cols = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    fast = [imu_csv.read(p, cols) for p in (table, commented)]
    assert imu_csv._read_table_fast(table, len("t,ax,ay,az,gx,gy,gz,n,s\r\n"), ",", list(range(7))) is not None
    assert imu_csv._read_table_fast(commented, len("t,ax,ay,az,gx,gy,gz\n"), ",", list(range(7))) is None
    monkeypatch.setattr(imu_csv, "_read_table_fast", lambda *a: None)
    slow = [imu_csv.read(p, cols) for p in (table, commented)]
    assert fast[0].skipped and all(_same_fields(a, b) for a, b in zip(fast, slow))
