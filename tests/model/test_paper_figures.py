"""The figures docs/model.md states about the paper (its table of differences and "Appendix B and
Theorem 1"), recomputed: each test is the computation behind one statement."""

from __future__ import annotations

import numpy as np
import sympy as sp

from softpvtol_gym import SoftPVTOLParams, dynamics


# ------------------------------------------------------------------------- #7: sin q / q vs cos(q/2)
def test_assumption_2_approximation_error():
    """|cos(q/2) - sin(q)/q| / |sin(q)/q| = |q / (2 sin(q/2)) - 1|: 4.2e-4 at 0.1, 0.11 at pi/2 and
    -> pi/2 - 1 = 0.57 as q -> pi (both sides vanish at pi; their ratio does not)."""
    q = sp.symbols("q", positive=True)
    rel = sp.simplify((sp.cos(q / 2) - sp.sin(q) / q) / (sp.sin(q) / q))
    assert sp.simplify(rel - (q / (2 * sp.sin(q / 2)) - 1)) == 0
    assert round(float(rel.subs(q, sp.Rational(1, 10))), 5) == 0.00042
    assert round(float(rel.subs(q, sp.pi / 2)), 2) == 0.11
    assert sp.limit(rel, q, sp.pi) == sp.pi / 2 - 1
    assert round(float(sp.pi / 2 - 1), 2) == 0.57


# ------------------------------------------------------------------- #11: eigenvalues of D on R^2
def _paper_mass_matrix_closed_form(ql, qr, p):
    """The paper's D in closed form (valid away from q = 0), for curvatures beyond the package's 2 pi."""
    def d12(q):
        return (np.sin(q) - q * np.cos(q)) / q**2, (np.cos(q) + q * np.sin(q) - 1) / q**2

    (d1l, d2l), (d1r, d2r) = d12(ql), d12(qr)
    D = np.zeros(np.shape(ql) + (5, 5))
    D[..., 0, 0] = D[..., 1, 1] = p.total_mass
    D[..., 2, 2] = p.I
    D[..., 0, 3] = D[..., 3, 0] = p.m_l * p.l_l * d1l
    D[..., 1, 3] = D[..., 3, 1] = p.m_l * p.l_l * d2l
    D[..., 0, 4] = D[..., 4, 0] = -p.m_r * p.l_r * d1r
    D[..., 1, 4] = D[..., 4, 1] = p.m_r * p.l_r * d2r
    D[..., 3, 3] = p.m_l * p.l_l**2 * (d1l**2 + d2l**2) + p.I_l
    D[..., 4, 4] = p.m_r * p.l_r**2 * (d1r**2 + d2r**2) + p.I_r
    return D


def test_mass_matrix_eigenvalues_bounded_on_the_whole_plane():
    """lambda(D) in [0.100, 7.02] for every (q_l, q_r) in R^2 with the paper's parameters: the lower
    bound min(m, I, I_l, I_r) = 0.1 from the sum-of-squares form (approached as |q| -> inf, where D ->
    diag(M, M, I, I_l, I_r)), the largest eigenvalue 7.018 at q = 0. No |q| <= pi assumption needed."""
    p = SoftPVTOLParams()
    g = np.linspace(-2 * np.pi, 2 * np.pi, 241)
    q = np.zeros((241, 241, 5))
    q[..., 3], q[..., 4] = np.meshgrid(g, g, indexing="ij")
    eig = np.linalg.eigvalsh(dynamics.mass_matrix(q, p))
    far = np.linspace(2 * np.pi, 300.0, 300)
    far = np.concatenate([-far, far])
    QL, QR = np.meshgrid(far, np.concatenate([g[np.abs(g) > 0.5], far]), indexing="ij")
    eig_far = np.linalg.eigvalsh(_paper_mass_matrix_closed_form(QL, QR, p))
    lo, hi = min(eig.min(), eig_far.min()), max(eig.max(), eig_far.max())
    assert lo >= 0.1 and round(lo, 3) == 0.100
    lam0 = np.linalg.eigvalsh(dynamics.mass_matrix(np.zeros(5), p))
    assert hi == lam0.max() and round(hi, 2) == 7.02


# ---------------------------------------------------------------------------------- Appendix B
def _appendix_b_symbols():
    q = sp.symbols("q_l", real=True)
    th1, th2, th3, th5, ll = sp.symbols("Theta_1 Theta_2 Theta_3 Theta_5 l_l", positive=True)
    d1 = (sp.sin(q) - q * sp.cos(q)) / q**2
    d2 = (sp.cos(q) + q * sp.sin(q) - 1) / q**2
    d5 = (q**2 + 2 - 2 * sp.cos(q) - 2 * q * sp.sin(q)) / q**4
    return q, th1, th2, th3, th5, ll, d1, d2, d5


def test_appendix_b_det_d4_carries_theta3_to_the_fourth():
    """D_4 (the leading 4x4 block of D) = Theta_3 * A with the printed A, so det(D_4) = Theta_3^4 det(A),
    not Theta_3 det(A); D_5 = D_1^2 + D_2^2; det(D_4) = Theta_1 Theta_2 (Theta_1 I_l + m_l l^2 D_5 (Theta_1 - m_l))."""
    q, th1, th2, th3, th5, ll, d1, d2, d5 = _appendix_b_symbols()
    assert sp.simplify(d1**2 + d2**2 - d5) == 0
    D4 = sp.Matrix([[th1, 0, 0, th3 * d1], [0, th1, 0, th3 * d2], [0, 0, th2, 0],
                    [th3 * d1, th3 * d2, 0, ll * th3 * d5 + th5]])
    rho1, rho2, rho3 = th1 / th3, th2 / th3, th5 / th3
    A = sp.Matrix([[rho1, 0, 0, d1], [0, rho1, 0, d2], [0, 0, rho2, 0], [d1, d2, 0, ll * d5 + rho3]])
    assert sp.simplify(D4 - th3 * A) == sp.zeros(4, 4)
    assert sp.simplify(D4.det() - th3**4 * A.det()) == 0
    assert sp.simplify(D4.det() - th3 * A.det()) != 0
    ml = th3 / ll  # Theta_3 = l_l m_l
    assert sp.simplify(D4.det() - th1 * th2 * (th1 * th5 + ml * ll**2 * d5 * (th1 - ml))) == 0


def test_appendix_b_figures_with_the_papers_parameters():
    """With the paper's parameters (Theta_1 = 7, Theta_2 = 1, Theta_3 = 0.5, Theta_5 = 0.1, l = 0.5):
    the sufficient condition (2 l rho_1)(1/8 + rho_3/(2 l)) < 1 reads 4.55 < 1 (violated); the printed
    'worst case' lower bound Theta_3 rho_1 rho_2 [(2 l rho_1)(1/8 + rho_3/(2 l)) - 1/4] = 60.2 exceeds
    det(D_4) everywhere: its true value at q = 0 is 7.525 (= the bound with Theta_3^4), and q = 0 is
    det(D_4)'s maximum (D_5 is largest there), not its worst case, which is the limit |q| -> inf,
    Theta_1^2 Theta_2 I_l = 4.9."""
    p = SoftPVTOLParams()
    th1, th2, th3, th5, ll = p.total_mass, p.I, p.l_l * p.m_l, p.I_l, p.l_l
    rho1, rho2, rho3 = th1 / th3, th2 / th3, th5 / th3
    cond = (2 * ll * rho1) * (1 / 8 + rho3 / (2 * ll))
    assert round(cond, 2) == 4.55
    printed = th3 * rho1 * rho2 * (cond - 0.25)
    assert round(printed, 1) == 60.2
    assert np.isclose(th3**4 * rho1 * rho2 * (cond - 0.25), 7.525, rtol=1e-12)
    g = np.linspace(-2 * np.pi, 2 * np.pi, 4001)
    q = np.zeros((4001, 5))
    q[:, 3] = g
    det4 = np.linalg.det(dynamics.mass_matrix(q, p)[:, :4, :4])
    assert np.isclose(det4.max(), 7.525, rtol=1e-12) and g[det4.argmax()] == 0.0
    assert det4.max() < printed
    assert np.isclose(th1**2 * th2 * p.I_l, 4.9) and det4.min() > 4.9


# ------------------------------------------------------------------------------ Theorem 1's proof
def test_theorem_1_proof_corrections():
    """Per coordinate (K, Lambda diagonal): with r = e' + lambda e, Vdot = -k e'^2 - lambda^2 k e^2
    (eq. lyapn_finall, correct); in (r, e) it is -k r^2 + 2 k lambda r e - 2 lambda^2 k e^2 (the paper
    prints -lambda^2 k e^2: a factor 2 missing), i.e. -z^T Q z with Q = [[K, -K Lambda], [-K Lambda,
    2 Lambda K Lambda]] (the paper prints +K Lambda off the diagonal); and V = +z^T P z (the paper
    prints a minus sign)."""
    k, lam, d = sp.symbols("k lambda d", positive=True)
    e, ed, r = sp.symbols("e ed r", real=True)
    vdot_e = -ed * k * ed - e * lam * k * lam * e
    in_r = sp.expand(vdot_e.subs(ed, r - lam * e))
    assert sp.expand(in_r - (-k * r**2 + 2 * k * lam * r * e - 2 * lam**2 * k * e**2)) == 0
    printed = -k * r**2 - lam**2 * k * e**2 + 2 * r * k * lam * e
    assert sp.expand(in_r - printed) != 0
    z = sp.Matrix([r, e])
    Q = sp.Matrix([[k, -k * lam], [-k * lam, 2 * lam * k * lam]])
    assert sp.expand(in_r + (z.T * Q * z)[0]) == 0
    Q_printed = sp.Matrix([[k, k * lam], [k * lam, 2 * lam * k * lam]])
    assert sp.expand(in_r + (z.T * Q_printed * z)[0]) != 0
    assert sp.simplify(Q.det() - Q_printed.det()) == 0  # the sign error does not change det(Q) > 0
    V = sp.Rational(1, 2) * r * d * r + e * lam * k * e
    P = sp.Matrix([[d / 2, 0], [0, lam * k]])
    assert sp.expand(V - (z.T * P * z)[0]) == 0


# ------------------------------------------------------------------ #12: RK4 at the paper's step
def test_committed_rk4_step_error_of_the_paper_loop():
    """results/model_figures.json (python baselines/model_figures.py): RK4 at 0.01 s vs RK4 at
    0.0005 s of the paper's actuated loop differ by up to 7.2e-3 m in x (t = 1.48 s) and 1.9e-3 m in z,
    beyond plotting accuracy; both maxima lie in the first 2 s, recomputed here."""
    import json
    from pathlib import Path

    from softpvtol_gym.baselines.figures.model import compare

    data = json.loads((Path(__file__).resolve().parents[2] / "results/model_figures.json").read_text())
    committed = data["comparisons"]["rk4_0.01_vs_rk4_0.0005"]
    assert committed["t_of_max_x_s"] <= 2.0 and committed["t_of_max_z_s"] <= 2.0
    now_all = compare(2.0, data["passes"], steps=(0.01, 0.0005))
    now = now_all["rk4_0.01_vs_rk4_0.0005"]
    assert now == committed
    # the arm references' largest change per 0.01 s step (q_r^d: 0.26 rad; the quadrant-correct
    # allocation has no jumps) happens in those 2 s too
    jumps = data["arm_reference_jumps"]["largest_arm_reference_change_per_0.01_s_step_rad"]
    assert now_all["largest_arm_reference_change_per_0.01_s_step_rad"] == jumps and round(max(jumps), 2) == 0.26
    assert round(now["max_abs_x_m"], 4) == 0.0072 and round(now["max_abs_z_m"], 4) == 0.0019
    # the reference is converged far below that: 0.001 s vs 0.0005 s
    ref = data["comparisons"]["rk4_0.001_vs_rk4_0.0005"]
    assert max(ref["max_abs_x_m"], ref["max_abs_z_m"]) < 1e-6
