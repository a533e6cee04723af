"""Closed-loop metrics of the paper's Tables 4 and 5, and the statistics to compare them.

Navigation (Table 4), per episode, from privileged ground truth:
    centroid error   distance of the target's image centroid from the image centre (px)
    bbox width       the target's bounding-box width (px), a proxy for following distance
    success          share of frames with the target within `radius` of the image centre;
                     the paper's 200 px at 640 px, scaled with the image width
    strict success   the same within 50 px at 640 px: the paper's radius is a quarter of
                     the image width wide, and a robot that holds still scores 19-28 % on it
    episode success  1 if the target was within the paper's radius for >= 90 % of the
                     episode's frames, else 0: a per-episode outcome to count and pair
    duration         seconds per trial
Frames where the target is not visible count as failures and are left out of the error
and width means (their share is reported as `visible`).

Manipulation (Table 5), per prediction:
    position error   |p_pred - p_expert| in mm
    accuracy         share within 50 mm and 15 degrees of yaw (yaw compared modulo 90
                     degrees: a cube looks the same after a quarter turn)
and per episode, the grasp of the last prediction (the sim's finish(): sebvs/sim/arm.py):
    grasp success    the cube lifted and held; episodes where nothing was graspable at the
                     end (the task asked for HOME) are not grasp trials
    end decision     HOME versus grasp at the end, against the task's rule
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

PAPER_RADIUS_PX = 200.0
PAPER_WIDTH_PX = 640.0
STRICT_RADIUS_PX = 50.0          # at 640 px, scaled like the paper's radius
EPISODE_SUCCESS_SHARE = 0.9      # of an episode's frames within the paper's radius
ARM_POSITION_TOL_MM = 50.0
ARM_YAW_TOL_DEG = 15.0


def success_radius(image_width: int, radius_px: float = PAPER_RADIUS_PX) -> float:
    """A success radius given at 640 px (the paper's 200 px by default), scaled to
    ``image_width``."""
    return radius_px * image_width / PAPER_WIDTH_PX


@dataclass
class NavEpisodeMetrics:
    frames: int
    visible: float              # share of frames with the target in view
    centroid_error_px: float    # mean over visible frames (nan if none)
    centroid_error_std_px: float
    bbox_width_px: float        # mean over visible frames
    success: float              # share of all frames within the radius
    duration_s: float
    strict_success: float = math.nan    # share of all frames within the strict radius
    episode_success: float = math.nan   # 1.0 if success >= EPISODE_SUCCESS_SHARE, else 0.0

    def as_dict(self) -> dict:
        return asdict(self)


def nav_episode_metrics(centroids: np.ndarray, bbox_widths: np.ndarray, visible: np.ndarray,
                        image_size: tuple[int, int], duration_s: float) -> NavEpisodeMetrics:
    """Metrics of one navigation episode.

    centroids: [T, 2] target centroid (u, v) in px; bbox_widths: [T] px;
    visible: [T] bool; image_size: (width, height) px.
    """
    centroids = np.asarray(centroids, dtype=np.float64).reshape(-1, 2)
    widths = np.asarray(bbox_widths, dtype=np.float64).reshape(-1)
    visible = np.asarray(visible, dtype=bool).reshape(-1)
    if not (len(centroids) == len(widths) == len(visible)):
        raise ValueError(f"lengths differ: centroids {len(centroids)}, widths {len(widths)}, "
                         f"visible {len(visible)}")
    if len(visible) == 0:
        raise ValueError("an episode without frames has no metrics")
    width, height = image_size
    centre = np.array([width / 2.0, height / 2.0])
    err = np.linalg.norm(centroids - centre, axis=1)
    ok = visible & np.isfinite(err)
    radius = success_radius(width)
    success = float((ok & (err <= radius)).mean())
    return NavEpisodeMetrics(
        frames=int(len(visible)),
        visible=float(ok.mean()),
        centroid_error_px=float(err[ok].mean()) if ok.any() else math.nan,
        centroid_error_std_px=float(err[ok].std()) if ok.any() else math.nan,
        bbox_width_px=float(widths[ok].mean()) if ok.any() else math.nan,
        success=success,
        duration_s=float(duration_s),
        strict_success=float((ok & (err <= success_radius(width, STRICT_RADIUS_PX))).mean()),
        episode_success=float(success >= EPISODE_SUCCESS_SHARE),
    )


def centre_error_px(truth: dict) -> float | None:
    """Distance of the target centroid from the image centre, px (None when not visible):
    the per-tick centroid error of a navigation truth dict (centroid, image, visible)."""
    if not truth.get("visible"):
        return None
    (u, v), (w, h) = truth["centroid"], truth["image"]
    return float(math.hypot(u - w / 2, v - h / 2))


def episode_duration(times, control_hz: float) -> float:
    """Seconds an episode's control ticks span (the sim publishes a control sample at both
    ends of an episode): last minus first tick time, one control period for one tick."""
    return times[-1] - times[0] if len(times) > 1 else 1 / control_hz


def nav_truth_metrics(truths: list, duration_s: float) -> dict:
    """Table 4 of one episode (or a segment of one) from its control ticks' nav truth
    dicts (sebvs.sim.nav.NavScene.truth): what the nav tracker records, and the nav
    environment's episode metrics (sebvs.envs)."""
    w, h = truths[0]["image"]
    return nav_episode_metrics([t["centroid"] for t in truths],
                               [t["bbox"][2] - t["bbox"][0] for t in truths],
                               [t["visible"] for t in truths], (w, h), duration_s).as_dict()


def arm_episode_summary(truths: list, reference, actions: list, outcome: str | None,
                        objects: int, lead_s: float, duration_s: float) -> dict:
    """Table 5 of one arm episode: {"metrics", "trace_error_mm"}, what the arm tracker
    records and the arm environment's episode metrics (sebvs.envs).

    truths [T] the control ticks' arm truth dicts, reference [T, 6] the task's pose at
    each tick (sebvs.experts.arm.leading_poses of the truths' expert_pose, led by
    ``lead_s`` as the expert that made the labels leads a moving cube), actions [T] the
    pose commanded at each tick (None where none came), outcome the scene's finish()
    outcome."""
    kept = [k for k, a in enumerate(actions) if a is not None]
    pred = np.array([np.asarray(actions[k], np.float64).reshape(6) for k in kept]).reshape(-1, 6)
    expert = np.array([reference[k] for k in kept], dtype=np.float64).reshape(-1, 6)
    scored = [truths[k] for k in kept]
    metrics = {"scenario": "single" if objects == 1 else "multi",
               **arm_metrics(pred, expert),
               "pred": np.round(pred, 5).tolist(), "expert": np.round(expert, 5).tolist(),
               "modes": [t["mode"] for t in scored],
               # where every cube was at each scored tick, so a miss can be told
               # apart: aimed at another cube, between cubes, or near the right one
               "target": [t.get("target", -1) for t in scored],
               "cubes_mm": [_cubes_mm(t) for t in scored],
               "reference_lead_s": lead_s,
               "outcome": outcome, "grasp_success": grasp_success(outcome),
               "end_decision_correct": end_decision_correct(outcome),
               "duration_s": duration_s}
    return {"metrics": metrics,
            "trace_error_mm": np.round(np.linalg.norm(pred[:, :3] - expert[:, :3], axis=1)
                                       * 1e3, 2).tolist()}


def _cubes_mm(truth: dict) -> list:
    """[[x mm, y mm, visible 0/1], ...] of the truth's cubes at one tick, index = cube."""
    return [[round(c["pos"][0] * 1e3, 1), round(c["pos"][1] * 1e3, 1), int(c["visible"])]
            for c in truth.get("cubes", ())]


# The arm scene's end-of-episode outcomes (sebvs.sim.arm.ArmScene.finish) that are not
# grasp trials: nothing graspable was there, whatever was commanded.
NOT_A_GRASP_TRIAL = ("home_correct", "grasp_unwanted")


def grasp_success(outcome: str | None) -> bool | None:
    """True if the last pose lifted and held the target cube; None when the episode was
    not a grasp trial (or has no outcome); False for every failure, including HOME
    commanded while a cube was graspable ("home_missed")."""
    if not outcome or outcome in NOT_A_GRASP_TRIAL:
        return None
    return outcome == "lifted_and_held"


def end_decision_correct(outcome: str | None) -> bool | None:
    """Did the last command choose HOME exactly when the task said HOME?"""
    if not outcome:
        return None
    return outcome not in ("home_missed", "grasp_unwanted")


def yaw_error_deg(yaw_pred, yaw_true, symmetry_deg: float = 90.0) -> np.ndarray:
    """Smallest yaw difference in degrees, modulo the object's rotational symmetry."""
    d = np.degrees(np.asarray(yaw_pred, dtype=np.float64) - np.asarray(yaw_true, np.float64))
    d = np.mod(d + symmetry_deg / 2, symmetry_deg) - symmetry_deg / 2
    return np.abs(d)


def arm_metrics(pred: np.ndarray, expert: np.ndarray,
                position_tol_mm: float = ARM_POSITION_TOL_MM,
                yaw_tol_deg: float = ARM_YAW_TOL_DEG) -> dict:
    """Table 5's error and accuracy. pred, expert: [N, 6] poses (x, y, z m; roll, pitch, yaw rad)."""
    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 6)
    expert = np.asarray(expert, dtype=np.float64).reshape(-1, 6)
    if pred.shape != expert.shape:
        raise ValueError(f"shapes differ: pred {pred.shape}, expert {expert.shape}")
    pos_mm = np.linalg.norm(pred[:, :3] - expert[:, :3], axis=1) * 1e3
    yaw = yaw_error_deg(pred[:, 5], expert[:, 5])
    within = (pos_mm <= position_tol_mm) & (yaw <= yaw_tol_deg)
    return {"n": int(len(pos_mm)),
            "position_error_mm": float(pos_mm.mean()) if len(pos_mm) else math.nan,
            "position_error_std_mm": float(pos_mm.std()) if len(pos_mm) else math.nan,
            "yaw_error_deg": float(yaw.mean()) if len(yaw) else math.nan,
            "accuracy": float(within.mean()) if len(within) else math.nan,
            "position_tol_mm": position_tol_mm, "yaw_tol_deg": yaw_tol_deg}


def wilson_interval(successes: float, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95% Wilson score interval of a proportion (successes may be fractional frame counts)."""
    if n <= 0:
        return (math.nan, math.nan)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def _binom_two_sided(k: int, n: int) -> float:
    """Exact two-sided p-value of k successes in n fair coin flips."""
    if n == 0:
        return 1.0
    probs = np.array([math.comb(n, i) for i in range(n + 1)], dtype=np.float64) / 2.0 ** n
    return float(min(1.0, probs[probs <= probs[k] * (1 + 1e-12)].sum()))


def paired_comparison(a, b, seed: int = 0, n_boot: int = 2000) -> dict:
    """Compare two modalities on the same seeds: per-seed values ``a`` and ``b``.

    Returns the mean difference a - b, its 95% bootstrap interval (seeded), and the exact
    sign test's two-sided p-value over the seeds where they differ.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"paired values need the same seeds: {a.shape} vs {b.shape}")
    d = a - b
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"n": 0, "mean_diff": math.nan, "ci95": [math.nan, math.nan], "p_sign": 1.0,
                "wins": 0, "losses": 0, "ties": 0}
    rng = np.random.default_rng(seed)
    boots = d[rng.integers(0, d.size, (n_boot, d.size))].mean(axis=1)
    wins, losses = int((d > 0).sum()), int((d < 0).sum())
    return {"n": int(d.size), "mean_diff": float(d.mean()),
            "ci95": [float(np.percentile(boots, 2.5)), float(np.percentile(boots, 97.5))],
            "p_sign": _binom_two_sided(min(wins, losses), wins + losses),
            "wins": wins, "losses": losses, "ties": int(d.size - wins - losses)}


def points(share: float) -> str:
    """A difference of shares in signed percentage points, one decimal; a mean that sums
    to zero in floating point (-1e-17) reads +0.0, not -0.0."""
    return f"{round(100 * share, 1) + 0.0:+.1f}"
