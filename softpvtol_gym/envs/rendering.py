"""pygame drawing of the Soft-PVTOL (gymnasium classic_control style)."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .. import model as MK
from ..params import P_EPS, P_LL, P_LR
from .config import EnvConfig
from .termination import GROUND_Z

WIDTH, HEIGHT = 600, 450
_ARC_POINTS = 16
MIN_VIEW_WIDTH = 8.0  # m


def task_view(spec) -> tuple[float, float, float]:
    """World window (x_min, x_max, z_min) of a task (z_max follows from the aspect ratio): its
    ``view``, or one fitted to its reference's x range over the episode (2.5 m margins, >= 8 m wide)."""
    if spec.view is not None:
        return spec.view
    pos = spec.evaluate(np.linspace(0.0, spec.episode_seconds, 201))[0]
    x0, x1 = float(pos[:, 0].min()) - 2.5, float(pos[:, 0].max()) + 2.5
    if x1 - x0 < MIN_VIEW_WIDTH:
        c = 0.5 * (x0 + x1)
        x0, x1 = c - 0.5 * MIN_VIEW_WIDTH, c + 0.5 * MIN_VIEW_WIDTH
    return x0, x1, min(GROUND_Z - 0.5, float(pos[:, 1].min()) - 2.0)


class Renderer:
    def __init__(self, cfg: EnvConfig, mode: str, fps: int):
        try:
            import pygame
        except ImportError as e:
            raise ImportError(f"render_mode={mode!r} needs pygame, which the 'render' extra installs: "
                              f'pip install "softpvtol-gym[render]"') from e
        self.pg = pygame
        self.cfg = cfg
        self.mode = mode
        self.fps = fps
        x0, x1, z0 = task_view(cfg.task_spec)
        self.scale = WIDTH / (x1 - x0)
        self.x0, self.z0 = x0, z0
        self.trail: deque = deque(maxlen=300)
        self.screen = None
        self.clock = None

    def clear_trail(self) -> None:
        self.trail.clear()

    def _px(self, x: float, z: float) -> tuple[int, int]:
        return int(round((x - self.x0) * self.scale)), int(round(HEIGHT - (z - self.z0) * self.scale))

    def draw(self, q, q_ref, p, applied, t):
        pg = self.pg
        if self.screen is None:
            if self.mode == "human":
                # classic_control: a display window, flipped and ticked at metadata["render_fps"]; only the
                # display is initialised (pygame.init() would start audio too: ALSA errors on headless machines)
                pg.display.init()
                pg.display.set_caption("SoftPVTOL-v0")
                self.screen = pg.display.set_mode((WIDTH, HEIGHT))
                self.clock = pg.time.Clock()
            else:
                # off-screen surface: needs no pygame.init(), so closing it cannot tear down a
                # window that another env in the same process has open
                self.screen = pg.Surface((WIDTH, HEIGHT))
        surf = pg.Surface((WIDTH, HEIGHT))
        surf.fill((255, 255, 255))
        x, z, th, ql, qr = (float(v) for v in q)
        ok = all(math.isfinite(v) for v in (x, z, th, ql, qr))
        # ground
        gy = self._px(0.0, GROUND_Z)[1]
        pg.draw.rect(surf, (215, 225, 205), pg.Rect(0, gy, WIDTH, HEIGHT - gy))
        pg.draw.line(surf, (90, 110, 80), (0, gy), (WIDTH, gy), 2)
        # trail and reference
        if ok:
            self.trail.append(self._px(x, z))
        if len(self.trail) > 1:
            pg.draw.lines(surf, (150, 170, 230), False, list(self.trail), 2)
        rx, rz = self._px(float(q_ref[0]), float(q_ref[1]))
        pg.draw.circle(surf, (220, 40, 40), (rx, rz), 6, 2)
        pg.draw.line(surf, (220, 40, 40), (rx - 9, rz), (rx + 9, rz), 1)
        pg.draw.line(surf, (220, 40, 40), (rx, rz - 9), (rx, rz + 9), 1)
        if ok:
            ct, st = math.cos(th), math.sin(th)
            eps = float(p[P_EPS])
            tips = []
            for side, qa, length in ((-1.0, ql, float(p[P_LL])), (1.0, qr, float(p[P_LR]))):
                pts = []
                for s in np.linspace(0.0, 1.0, _ARC_POINTS):
                    bx, bz = MK.arm_offset(s * qa, s * length, eps, side)
                    pts.append(self._px(x + ct * bx - st * bz, z + st * bx + ct * bz))
                pg.draw.lines(surf, (40, 40, 40), False, pts, 4)
                pg.draw.circle(surf, (60, 60, 160), pts[-1], 6)
                tips.append(pts[-1])
            # body
            bw, bh = 0.18, 0.10
            corners = [(-bw, -bh), (bw, -bh), (bw, bh), (-bw, bh)]
            poly = [self._px(x + ct * cx - st * cz, z + st * cx + ct * cz) for cx, cz in corners]
            pg.draw.polygon(surf, (70, 70, 70), poly)
            # thrust vectors: left along R(theta) (sin q_l, cos q_l), right along R(theta) (-sin q_r, cos q_r)
            tmax = self.cfg.thrust_max
            for i, (tip, qa, sgn) in enumerate(((tips[0], ql, 1.0), (tips[1], qr, -1.0))):
                T = float(applied[i])
                if not math.isfinite(T):
                    continue
                L = 1.2 * T / tmax * self.scale
                dx, dz = sgn * math.sin(qa), math.cos(qa)
                wx, wz = ct * dx - st * dz, st * dx + ct * dz
                end = (int(round(tip[0] + L * wx)), int(round(tip[1] - L * wz)))
                pg.draw.line(surf, (230, 130, 20), tip, end, 3)
        self.screen.blit(surf, (0, 0))
        if self.mode == "human":
            pg.event.pump()
            self.clock.tick(self.fps)
            pg.display.flip()
            return None
        return np.transpose(np.array(pg.surfarray.pixels3d(self.screen)), axes=(1, 0, 2)).copy()

    def close(self) -> None:
        """Close the window (human mode) or drop the surface; safe to call more than once."""
        if self.screen is not None:
            if self.mode == "human":
                self.pg.display.quit()
                self.pg.quit()
            self.screen = None
            self.clock = None
