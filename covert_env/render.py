"""Pictures of the model with matplotlib (imported lazily): terrain, road, target, zones and shadows.

``scene_figure`` draws the kind of picture of the paper's Figs. 5, 6 and 10: a 3D view of the
polytopes, the road and the target, and a top view of the feasible zone (eq. 5), the shadows
(eqs. 8-9) and the visible zone (eq. 10) at one slot, with the UAVs if given.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from covert_env.scenario import Scenario

__all__ = ["scene_figure", "draw_top_view", "draw_3d_view", "EpisodeRenderer", "save_episode_gif", "save_episode_mp4"]

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


def _fill(ax, geom, **kw):
    for poly in _geoms(geom):
        x, y = poly.exterior.xy
        ax.fill(x, y, **kw)
        kw.pop("label", None)


def _outline(ax, geom, **kw):
    for poly in _geoms(geom):
        for ring in [poly.exterior, *poly.interiors]:
            x, y = ring.xy
            ax.plot(x, y, **kw)
            kw.pop("label", None)


def zones_at(scenario: Scenario, k: int):
    """(feasible zone, shadow polygons, visible zone) at slot k, as used by the pictures."""
    from covert_env.visibility import shadow_polygons
    from covert_env.zone import feasible_zone, visible_zone

    c = scenario.config
    q = scenario.track.position(k)
    phi = float(scenario.track.heading(k))
    zone = feasible_zone(q[:2], phi, c.r1, c.r2, c.mu, c.r_u)
    shadows = shadow_polygons(scenario.terrain, q, c.altitude, c.r2 + c.shadow_margin, h_min=c.h_min)
    return zone, shadows, visible_zone(zone, shadows)


def draw_top_view(ax, scenario: Scenario, k: int, uav_xy=None, trails=None, legend: bool = True) -> None:
    """Top view at slot k: footprints, road, target, feasible zone, shadows, visible zone, UAVs."""
    c = scenario.config
    q = scenario.track.position(k)
    zone, shadows, visible = zones_at(scenario, k)
    for i, p in enumerate(scenario.terrain):
        _fill(ax, p.footprint, color=TERRAIN_COLOR, alpha=0.8, label="terrain footprint" if i == 0 else None)
    road = scenario.road.points
    ax.plot(road[:, 0], road[:, 1], color=ROAD_COLOR, lw=1.0, ls="--", label="road")
    first = True
    for s in shadows:
        if not s.is_empty:
            _fill(ax, s, color=SHADOW_COLOR, alpha=0.25, label="shadows (eqs. 8-9)" if first else None)
            first = False
    _outline(ax, zone, color=ZONE_COLOR, lw=1.5, label="feasible zone (eq. 5)")
    _fill(ax, visible, color=VISIBLE_COLOR, alpha=0.35, label="visible zone (eq. 10)")
    _outline(ax, visible, color=VISIBLE_COLOR, lw=1.0, ls=":")
    ax.plot(*q[:2], marker="*", ms=14, color="gold", mec="k", label="target", ls="none")
    if trails is not None:
        for i, tr in enumerate(np.asarray(trails)):
            ax.plot(tr[:, 0], tr[:, 1], color=UAV_COLORS[i % len(UAV_COLORS)], lw=1.0, alpha=0.7)
    if uav_xy is not None:
        for i, p in enumerate(np.asarray(uav_xy).reshape(-1, 2)):
            ax.plot(*p, marker="^", ms=9, color=UAV_COLORS[i % len(UAV_COLORS)], mec="k", ls="none",
                    label=f"uav_{i}")
    r = c.r2 + 40
    ax.set_xlim(q[0] - r, q[0] + r)
    ax.set_ylim(q[1] - r, q[1] + r)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"top view at slot {k}, plane z = h = {c.altitude:g} m")
    if legend:
        ax.legend(loc="upper left", fontsize=7, framealpha=0.8)


def draw_3d_view(ax, scenario: Scenario, k: int, uav_xy=None) -> None:
    """3D view: polytopes as faces, the road, the target and the UAVs at altitude h."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    c = scenario.config
    faces = []
    for p in scenario.terrain:
        n = p.n_vertices
        base = np.column_stack([p.base, np.zeros(n)])
        faces.append(p.top)
        for j in range(n):
            faces.append(np.array([base[j], base[(j + 1) % n], p.top[(j + 1) % n], p.top[j]]))
    ax.add_collection3d(Poly3DCollection(faces, facecolor=TERRAIN_COLOR, edgecolor="0.25", lw=0.3, alpha=0.9))
    road = scenario.road.points
    ax.plot(road[:, 0], road[:, 1], 0 * road[:, 0], color=ROAD_COLOR, lw=1.0)
    q = scenario.track.position(k)
    ax.scatter(*q, marker="*", s=120, color="gold", edgecolor="k")
    if uav_xy is not None:
        for i, p in enumerate(np.asarray(uav_xy).reshape(-1, 2)):
            ax.scatter(p[0], p[1], c.altitude, marker="^", s=50, color=UAV_COLORS[i % len(UAV_COLORS)])
            ax.plot([p[0], q[0]], [p[1], q[1]], [c.altitude, q[2]], color=UAV_COLORS[i % len(UAV_COLORS)],
                    lw=0.6, ls=":")
    lo = np.vstack([road.min(0), q[:2] - c.r2]).min(0)
    hi = np.vstack([road.max(0), q[:2] + c.r2]).max(0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(0, c.altitude * 1.1)
    ax.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], 0.25 * max(hi[0] - lo[0], hi[1] - lo[1])))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title("terrain, road and target (3D)")


def scene_figure(scenario: Scenario, k: int = 0, uav_xy=None, trails=None):
    """A figure with the 3D view (left) and the top view (right) at slot k."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(15, 6.5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    draw_3d_view(ax3, scenario, k, uav_xy)
    draw_top_view(ax2, scenario, k, uav_xy, trails)
    fig.suptitle(f"{scenario.name}: slot {k}")
    fig.tight_layout()
    return fig


class EpisodeRenderer:
    """Draws frames of a running :class:`~covert_env.engine.Engine` (top view with trails, or 3D).

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

    def draw(self, scenario: Scenario, engine) -> np.ndarray:
        """Draw the engine's current slot; returns the frame as uint8 (H, W, 3)."""
        fig = self._figure()
        fig.clf()
        trails = np.swapaxes(np.array(engine._xy), 0, 1)
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


def save_episode_gif(frames, path, fps: int = 4) -> None:
    """Write frames (uint8 H x W x 3) to an animated GIF with matplotlib's Pillow writer."""
    _save_animation(frames, path, fps, "pillow")


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
