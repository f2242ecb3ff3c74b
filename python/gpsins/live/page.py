"""The live status page on a loopback HTTP port (``gpsins live --http-port``): the track so far,
position and attitude with their sigmas, each source's NIS per degree of freedom against its 95 %
band, the counters (resets, gaps) and the alignment's warnings, refreshed once a second. Self
contained (no map tiles, no scripts from elsewhere: a vehicle computer has no network).

    /             the page
    /status.json  the last round's status (as status.jsonl's lines)
    /track.json   the track so far: north and east (m) from its first epoch, at most TRACK_POINTS
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np

TRACK_POINTS = 4000

PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>gpsins live</title>
<style>body{font:14px sans-serif;margin:1em}td{padding:0 .6em}svg{border:1px solid #999;background:#fafafa}
.warn{color:#b00}</style></head><body>
<h2>gpsins live <span id="t"></span></h2>
<svg id="map" width="480" height="480" viewBox="0 0 480 480"><polyline id="track" fill="none" stroke="#1f77b4"
stroke-width="1.5"/><circle id="now" r="4" fill="#d62728"/></svg>
<table id="state"></table><h3>NIS per degree of freedom (this round) against its 95 % band</h3>
<table id="nis"></table><h3>Counters</h3><table id="counters"></table><div id="warnings" class="warn"></div>
<script>
function rows(el, obj){el.innerHTML=Object.entries(obj).map(([k,v])=>`<tr><td>${k}</td><td>${v}</td></tr>`).join("")}
function fmt(a,d){return a.map(x=>x===null?"-":Number(x).toFixed(d)).join(" / ")}
async function tick(){
 try{
  const s=await (await fetch("status.json")).json(); const tr=await (await fetch("track.json")).json();
  document.getElementById("t").textContent="t = "+s.t.toFixed(1)+" s of GPS week "+s.week;
  rows(document.getElementById("state"),{"latitude, longitude (deg), height (m)":fmt(s.llh_deg_m,7),
   "sigma north / east / down (m)":fmt(s.sigma_ned_m,3),"yaw / pitch / roll (deg)":fmt(s.ypr_deg,2),
   "sigma yaw / pitch / roll (deg)":fmt(s.sigma_ypr_deg,2),"heading known":s.heading_known,
   "IMU samples, fixes, pseudoranges fed":[s.imu_fed,s.fixes_fed,s.pseudoranges_fed].join(", ")});
  rows(document.getElementById("nis"),Object.fromEntries(Object.entries(s.nis_per_dof).map(([k,v])=>
   [k,`${v.mean.toFixed(2)} over ${v.n} updates, band ${v.band[0].toFixed(2)}-${v.band[1].toFixed(2)}`+
   (v.mean<v.band[0]||v.mean>v.band[1]?" <b class=warn>outside</b>":"")])));
  rows(document.getElementById("counters"),s.counters);
  document.getElementById("warnings").innerHTML=s.warnings.map(w=>"<p>"+w+"</p>").join("");
  if(tr.north.length){const n=tr.north,e=tr.east;const lo=Math.min(...n,...e),hi=Math.max(...n,...e);
   const sc=440/Math.max(hi-lo,1);const x=v=>20+(v-Math.min(...e))*sc, y=v=>460-(v-Math.min(...n))*sc;
   document.getElementById("track").setAttribute("points",e.map((v,i)=>x(v)+","+y(n[i])).join(" "));
   const c=document.getElementById("now");c.setAttribute("cx",x(e[e.length-1]));c.setAttribute("cy",y(n[n.length-1]));}
 }catch(err){document.getElementById("warnings").textContent="no status yet"}
 setTimeout(tick,1000)}
tick();
</script></body></html>"""


class StatusPage:
    """Holds the last status and the track, and serves them on 127.0.0.1:port (0: any free)."""

    def __init__(self, port: int = 0):
        self.status: dict = {}
        self._north: list[float] = []
        self._east: list[float] = []
        self._origin = None
        self._lock = threading.Lock()
        page = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802 (http.server's name)
                path = self.path.split("?", 1)[0]
                if path in ("/", "/index.html"):
                    body, kind = PAGE.encode(), "text/html; charset=utf-8"
                elif path == "/status.json":
                    with page._lock:
                        body, kind = json.dumps(page.status).encode(), "application/json"
                elif path == "/track.json":
                    with page._lock:
                        body = json.dumps({"north": page._north, "east": page._east}).encode()
                    kind = "application/json"
                else:
                    self.send_error(404)
                    return
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *_):  # a status page polled once a second: no access log
                pass

        self._server = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self.port = self._server.server_address[1]
        threading.Thread(target=self._server.serve_forever, name="gpsins-status", daemon=True).start()

    def update(self, status: dict, r_ecef: np.ndarray, c_ne: np.ndarray) -> None:
        """The round's status (strict JSON) and its epochs' positions (ECEF) for the track, in the local
        frame (``c_ne``: ECEF -> NED) of the first round's first epoch."""
        with self._lock:
            self.status = status
            if self._origin is None:  # the track's frame: fixed at its first epoch
                self._origin, self._c_ne = r_ecef[0].copy(), c_ne.copy()
            ned = (r_ecef - self._origin) @ self._c_ne.T
            step = max(1, len(ned) // 50)  # about 50 points a round
            self._north += np.round(ned[::step, 0], 2).tolist()
            self._east += np.round(ned[::step, 1], 2).tolist()
            if len(self._north) > TRACK_POINTS:  # thin the old track, keep its shape
                self._north, self._east = self._north[::2], self._east[::2]

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
