"""Pictures of the model with matplotlib (imported lazily): terrain, road, target, zones and shadows.

``scene_figure`` draws the kind of picture of the paper's Figs. 5, 6 and 10: a 3D view of the
polytopes, the road and the target, and a top view of the feasible zone (eq. 5), the shadows
(eqs. 8-9) and the visible zone (eq. 10) at one slot, with the UAVs if given.
"""

from __future__ import annotations

import numpy as np

from covert_env.geometry.zone import feasible_zone, visible_zone
from covert_env.world.roles import EngineView
from covert_env.world.scenario import Scenario
from covert_env.world.shadows import shadow_polygons
from covert_env.world.visibility import line_of_sight

__all__ = ["scene_figure", "draw_top_view", "draw_3d_view", "zones_at", "shadow_share", "EpisodeRenderer",
           "fill_geometry", "outline_geometry",
           "episode_frames", "save_episode_gif", "save_episode_mp4"]

ZONE_COLOR = "black"
VISIBLE_COLOR = "tab:green"
SHADOW_COLOR = "tab:red"
TERRAIN_COLOR = "0.55"
ROAD_COLOR = "0.35"
UAV_COLORS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:cyan")


def _geoms(geom):
    """Polygons of a shapely Polygon/MultiPolygon/GeometryCollection."""
    if geom is None or geom.is_empty:
        return []
    if geom.geom_type == "Polygon":
        return [geom]
    return [g for part in getattr(geom, "geoms", []) for g in _geoms(part)]


def fill_geometry(ax, geom, **kw):
    """Fill every polygon of a shapely geometry on ``ax`` (one legend label, on the first)."""
    for poly in _geoms(geom):
        x, y = poly.exterior.xy
        ax.fill(x, y, **kw)
        kw.pop("label", None)


def outline_geometry(ax, geom, **kw):
    """Draw every ring of a shapely geometry on ``ax`` (one legend label, on the first)."""
    for poly in _geoms(geom):
        for ring in [poly.exterior, *poly.interiors]:
            x, y = ring.xy
            ax.plot(x, y, **kw)
            kw.pop("label", None)


def zones_at(scenario: Scenario, k: int, q=None, phi: float | None = None):
    """(feasible zone, shadow polygons, visible zone) at slot k, as used by the pictures.

    ``q`` (3,) and ``phi`` override the target's pose (e.g. between slot times)."""
    c = scenario.config
    q = scenario.track.position(k) if q is None else np.asarray(q, float)
    phi = float(scenario.track.heading(k)) if phi is None else float(phi)
    zone = feasible_zone(q[:2], phi, c.r1, c.r2, c.mu, c.r_u)
    shadows = shadow_polygons(scenario.terrain, q, c.altitude, c.r2 + c.shadow_margin, h_min=c.h_min)
    return zone, shadows, visible_zone(zone, shadows)


def shadow_share(scenario: Scenario, k: int) -> float:
    """Share of the feasible zone (eq. 5) at slot k that lies in shadow: ``1 - |visible zone| / |zone|``."""
    zone, _, visible = zones_at(scenario, k)
    return float(max(0.0, 1.0 - visible.area / zone.area)) if zone.area > 0 else 0.0


def draw_top_view(ax, scenario: Scenario, k: int, uav_xy=None, trails=None, legend: bool = True, *,
                  q=None, phi: float | None = None, los_lines: bool = False, radius: float | None = None,
                  center=None, title: str | None = None) -> None:
    """Top view at slot k: footprints, road, target, feasible zone, shadows, visible zone, UAVs.

    The shadows inside the feasible zone (where the earlier, shadow-blind method may fly and lose the line of
    sight) are filled solid red. ``q``/``phi`` override the target's pose (frames between slot times);
    ``los_lines`` draws each UAV's line of sight to the target, green when clear and red when blocked;
    ``radius`` (m) is the half-width of the view about ``center`` (default: r2 + 40 about the target).
    """
    c = scenario.config
    q = scenario.track.position(k) if q is None else np.asarray(q, float)
    zone, shadows, visible = zones_at(scenario, k, q, phi)
    for i, p in enumerate(scenario.terrain):
        fill_geometry(ax, p.footprint, color=TERRAIN_COLOR, alpha=0.8, label="terrain footprint" if i == 0 else None)
    road = scenario.road.points
    ax.plot(road[:, 0], road[:, 1], color=ROAD_COLOR, lw=1.0, ls="--", label="road")
    first = True
    for s in shadows:
        if not s.is_empty:
            fill_geometry(ax, s, color=SHADOW_COLOR, alpha=0.18, lw=0, label="shadows (eqs. 8-9)" if first else None)
            first = False
    fill_geometry(ax, visible, color=VISIBLE_COLOR, alpha=0.35, lw=0, label="visible zone (eq. 10)")
    in_zone = zone.difference(visible)
    if in_zone.area > 1e-6 * max(zone.area, 1.0):
        fill_geometry(ax, in_zone, facecolor=SHADOW_COLOR, alpha=0.75, edgecolor="darkred", lw=0.5,
              label="shadow inside the zone")
    outline_geometry(ax, zone, color=ZONE_COLOR, lw=1.5, label="feasible zone (eq. 5)")
    ax.plot(*q[:2], marker="*", ms=14, color="gold", mec="k", label="target", ls="none")
    if trails is not None:
        for i, tr in enumerate(np.asarray(trails)):
            ax.plot(tr[:, 0], tr[:, 1], color=UAV_COLORS[i % len(UAV_COLORS)], lw=1.0, alpha=0.7)
    if uav_xy is not None:
        pts = np.asarray(uav_xy, float).reshape(-1, 2)
        if los_lines:
            clear = line_of_sight(scenario.terrain, pts, c.altitude, q)
            for p, ok in zip(pts, clear, strict=True):
                ax.plot([p[0], q[0]], [p[1], q[1]], color="green" if ok else "red", lw=1.4 if ok else 2.0,
                        ls="-" if ok else "--", alpha=0.9)
        for i, p in enumerate(pts):
            ax.plot(*p, marker="^", ms=9, color=UAV_COLORS[i % len(UAV_COLORS)], mec="k", ls="none",
                    label=f"uav_{i}")
    r = c.r2 + 40 if radius is None else float(radius)
    cx, cy = q[:2] if center is None else np.asarray(center, float)
    ax.set_xlim(cx - r, cx + r)
    ax.set_ylim(cy - r, cy + r)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"top view at slot {k}, plane z = h = {c.altitude:g} m" if title is None else title)
    if legend:
        ax.legend(loc="upper left", fontsize=7, framealpha=0.8)


def draw_3d_view(ax, scenario: Scenario, k: int, uav_xy=None, extent=None) -> None:
    """3D view: polytopes as faces, the road, the target and the UAVs at altitude h.

    ``extent`` ((x0, y0), (x1, y1)) crops the view to that box (only polytopes that reach into it are
    drawn); the default is the whole road and the zone at slot k.
    """
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    c = scenario.config
    road = scenario.road.points
    q = scenario.track.position(k)
    if extent is None:
        lo = np.vstack([road.min(0), q[:2] - c.r2]).min(0)
        hi = np.vstack([road.max(0), q[:2] + c.r2]).max(0)
    else:
        lo, hi = (np.asarray(e, float) for e in extent)
    faces = []
    for p in scenario.terrain:
        b = np.asarray(p.base)
        if extent is not None and (np.any(b.max(0) < lo) or np.any(b.min(0) > hi)):
            continue
        n = p.n_vertices
        base = np.column_stack([b, np.zeros(n)])
        faces.append(p.top)
        for j in range(n):
            faces.append(np.array([base[j], base[(j + 1) % n], p.top[(j + 1) % n], p.top[j]]))
    if faces:
        ax.add_collection3d(Poly3DCollection(faces, facecolor=TERRAIN_COLOR, edgecolor="0.25", lw=0.3, alpha=0.9),
                           autolim=False)   # limits are set below; autoscaling a fresh 3D axes can overflow
    keep = np.all((road >= lo) & (road <= hi), axis=1) if extent is not None else np.ones(len(road), bool)
    ax.plot(road[keep, 0], road[keep, 1], 0 * road[keep, 0], color=ROAD_COLOR, lw=1.0)
    ax.scatter(*q, marker="*", s=120, color="gold", edgecolor="k")
    if uav_xy is not None:
        for i, p in enumerate(np.asarray(uav_xy).reshape(-1, 2)):
            ax.scatter(p[0], p[1], c.altitude, marker="^", s=50, color=UAV_COLORS[i % len(UAV_COLORS)])
            ax.plot([p[0], q[0]], [p[1], q[1]], [c.altitude, q[2]], color=UAV_COLORS[i % len(UAV_COLORS)],
                    lw=0.6, ls=":")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(0, c.altitude * 1.1)
    span = max(hi[0] - lo[0], hi[1] - lo[1])
    ax.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], max(0.25 * span, min(c.altitude * 1.1, 0.6 * span))))
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))
    ax.tick_params(labelsize=7, pad=0)
    ax.set_xlabel("x (m)", fontsize=8, labelpad=2)
    ax.set_ylabel("y (m)", fontsize=8, labelpad=2)
    ax.set_zlabel("z (m)", fontsize=8, labelpad=2)
    ax.set_title("terrain, road and target (3D)")


def scene_figure(scenario: Scenario, k: int = 0, uav_xy=None, trails=None):
    """A figure with the 3D view (left) and the top view (right) at slot k (in [0, n_slots])."""
    import matplotlib.pyplot as plt

    n = scenario.config.n_slots
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= n:
        raise ValueError(f"scene_figure: slot k must be an integer in [0, {n}] (n_slots), got {k!r}")

    fig = plt.figure(figsize=(15, 6.5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    draw_3d_view(ax3, scenario, k, uav_xy)
    draw_top_view(ax2, scenario, k, uav_xy, trails)
    fig.suptitle(f"{scenario.name}: slot {k}")
    fig.tight_layout()
    return fig


class EpisodeRenderer:
    """Draws frames of a running episode, an :class:`~covert_env.world.roles.EngineView` (top view with trails, or 3D).

    ``human=False`` renders off-screen with the Agg canvas and returns uint8 H x W x 3 frames;
    ``human=True`` opens a matplotlib window lazily and updates it.
    """

    def __init__(self, human: bool = False, view: str = "top", size=(640, 640), dpi: int = 80):
        if view not in ("top", "3d", "both"):
            raise ValueError(f"view must be 'top', '3d' or 'both', got {view!r}")
        self.human, self.view, self.size, self.dpi = human, view, size, dpi
        self._fig = None

    def _figure(self):
        if self._fig is None:
            w, h = self.size[0] / self.dpi, self.size[1] / self.dpi
            if self.human:
                import matplotlib.pyplot as plt

                plt.ion()
                self._fig = plt.figure(figsize=(w, h), dpi=self.dpi)
            else:
                from matplotlib.backends.backend_agg import FigureCanvasAgg
                from matplotlib.figure import Figure

                self._fig = Figure(figsize=(w, h), dpi=self.dpi)
                FigureCanvasAgg(self._fig)
        return self._fig

    def draw(self, scenario: Scenario, engine: EngineView) -> np.ndarray:
        """Draw the engine's current slot; returns the frame as uint8 (H, W, 3)."""
        fig = self._figure()
        fig.clf()
        trails = np.swapaxes(engine.positions, 0, 1)
        if self.view in ("top", "both"):
            ax = fig.add_subplot(1, 2 if self.view == "both" else 1, 2 if self.view == "both" else 1)
            draw_top_view(ax, scenario, engine.k, engine.uav_xy, trails, legend=False)
        if self.view in ("3d", "both"):
            ax3 = fig.add_subplot(1, 2 if self.view == "both" else 1, 1, projection="3d")
            draw_3d_view(ax3, scenario, engine.k, engine.uav_xy)
        fig.canvas.draw()
        frame = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        if self.human:
            import matplotlib.pyplot as plt

            plt.pause(0.001)
        return frame

    def close(self) -> None:
        if self._fig is not None and self.human:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
        self._fig = None


def episode_frames(scenario: Scenario, trajectory, *, frames_per_slot: int = 2, size=(480, 480), dpi: int = 80,
                   title: str = "", radius: float | None = None, trail: int = 8,
                   legend_every: bool = True) -> list[np.ndarray]:
    """Frames (uint8 H x W x 3) of a flown episode: top view following the target, with the feasible zone,
    the shadows (filled solid inside the zone), the visible zone, the UAVs with short trails and their lines
    of sight (green clear, red blocked).

    ``frames_per_slot`` frames per slot, at evenly spaced instants along each slot's flown path
    (``trajectory.path_xy``, ``trajectory.target_path_xyz``), plus the final slot time.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if int(frames_per_slot) < 1:
        raise ValueError(f"frames_per_slot must be >= 1, got {frames_per_slot}")
    f_n = int(frames_per_slot)
    path, tpath = np.asarray(trajectory.path_xy), np.asarray(trajectory.target_path_xyz)
    phis = np.unwrap(np.asarray(trajectory.target_phi, float))
    n_slots, _, n_samples = path.shape[:3]
    fig = Figure(figsize=(size[0] / dpi, size[1] / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    instants = [(k, j) for k in range(n_slots) for j in range(f_n)] + [(n_slots, 0)]
    frames = []
    for k, j in instants:
        if k < n_slots:
            idx = int(round(j / f_n * (n_samples - 1)))
            xy, q = path[k, :, idx], tpath[k, idx]
            phi = phis[k] + (phis[k + 1] - phis[k]) * j / f_n
            done = np.concatenate([trajectory.uav_xy[max(k - trail, 0):k + 1].swapaxes(0, 1),
                                   path[k, :, :idx + 1]], axis=1) if idx else \
                trajectory.uav_xy[max(k - trail, 0):k + 1].swapaxes(0, 1)
        else:
            xy, q, phi = trajectory.uav_xy[k], trajectory.target_xyz[k], phis[k]
            done = trajectory.uav_xy[max(k - trail, 0):k + 1].swapaxes(0, 1)
        fig.clf()
        ax = fig.add_axes((0.01, 0.01, 0.98, 0.91))
        # The zone lies between R1 and R2 behind the target: centre the view between the zone and the target.
        c = scenario.config
        center = np.asarray(q[:2]) - 0.5 * c.r2 * np.array([np.cos(phi), np.sin(phi)])
        draw_top_view(ax, scenario, k, xy, trails=done, legend=False, q=q, phi=phi, los_lines=True,
                      radius=0.75 * c.r2 if radius is None else radius, center=center, title="")
        if k == 0 and j == 0 or legend_every:
            ax.legend(handles=_gif_legend(len(xy)), loc="lower left", fontsize=6, framealpha=0.85, ncol=2)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_xlabel("")
        ax.set_ylabel("")
        fig.suptitle(f"{title}{' -- ' if title else ''}t = {k + j / f_n:.1f} s", fontsize=9, y=0.985)
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    return frames


def _gif_legend(n_uavs: int):
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    return [Patch(color=VISIBLE_COLOR, alpha=0.5, label="visible zone"),
            Patch(color=SHADOW_COLOR, alpha=0.75, label="shadow in zone"),
            Line2D([], [], color="green", label="LoS clear"), Line2D([], [], color="red", ls="--", label="LoS blocked"),
            *[Line2D([], [], marker="^", ls="none", color=UAV_COLORS[i % len(UAV_COLORS)], mec="k",
                     label=f"uav_{i}") for i in range(n_uavs)]]


def save_episode_gif(frames, path, fps: int = 4, colors: int = 64) -> None:
    """Write frames (uint8 H x W x 3) to a looping animated GIF with Pillow.

    One palette of ``colors`` colours is shared by every frame, without dithering (small files for flat-colour
    plots): the pictures' key colours (UAVs, target, zones, lines of sight) exactly, so that small markers keep
    their colours, and the rest adapted to a sample of the frames."""
    from matplotlib.colors import to_rgb
    from PIL import Image

    if isinstance(fps, bool) or not isinstance(fps, (int, np.integer)) or not 1 <= fps <= 100:
        raise ValueError(f"save_episode_gif: fps must be an integer in [1, 100], got {fps!r}")
    frames = [np.asarray(f, dtype=np.uint8) for f in frames]
    if not frames:
        raise ValueError("no frames to save")
    keys = [*UAV_COLORS, "gold", "green", "red", "darkred", "k", "w", VISIBLE_COLOR, SHADOW_COLOR, TERRAIN_COLOR]
    key_rgb = [round(255 * v) for c in keys for v in to_rgb(c)]
    n_free = max(2, int(colors) - len(keys))
    sample = np.concatenate(frames[:: max(1, len(frames) // 8)][:8], axis=0)
    free = Image.fromarray(sample).quantize(colors=n_free, method=Image.Quantize.MEDIANCUT).getpalette()[:3 * n_free]
    palette = Image.new("P", (1, 1))
    palette.putpalette(free + key_rgb)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    images[0].save(str(path), save_all=True, append_images=images[1:], duration=int(round(1000 / fps)), loop=0,
                   optimize=False, disposal=1)


def save_episode_mp4(frames, path, fps: int = 4) -> None:
    """Write frames to MP4 with matplotlib's ffmpeg writer (needs ffmpeg on PATH)."""
    _save_animation(frames, path, fps, "ffmpeg")


def _save_animation(frames, path, fps: int, writer: str) -> None:
    from matplotlib import animation
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    frames = [np.asarray(f) for f in frames]
    if not frames:
        raise ValueError("no frames to save")
    h, w = frames[0].shape[:2]
    fig = Figure(figsize=(w / 100, h / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.axis("off")
    im = ax.imshow(frames[0])
    anim = animation.FuncAnimation(fig, lambda i: (im.set_data(frames[i]), [im])[1], frames=len(frames),
                                   interval=1000 / fps, blit=True)
    if writer == "pillow":
        anim.save(str(path), writer=animation.PillowWriter(fps=fps))
    else:
        anim.save(str(path), writer=animation.FFMpegWriter(fps=fps))
