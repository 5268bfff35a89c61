#pragma once
/// @file Kobayashi.h
/// @brief The Kobayashi phase-field model of the ice paper (Kim, Henson & Lin 2004, eqs. 1-5):
///
///   tau dp/dt = div(eps^2 grad p) - d/dx(eps eps' dp/dy) + d/dy(eps eps' dp/dx) + n(p, T)
///   dT/dt     = lap T + K dp/dt
///   eps(theta) = eps_bar (1 + delta cos(j (theta0 - theta))),  theta = atan2(p_y, p_x)
///   n(p, T)    = p (1 - p) (p - 1/2 + m(T) + a chi),  m(T) = alpha/pi atan(gamma (T_e - T))
///
/// (a chi is Kobayashi's optional noise, chi uniform in [-1/2, 1/2], off by default.)
///
/// Two schemes:
///  - Euler: the full equations 1-2, forward Euler (the paper's dt 0.0002);
///  - second order (section 5): the simplified equation 8,
///      tau dp/dt = grad(eps^2) . grad p + eps^2 lap p + n(p, T),
///    with Lax-Wendroff on the advection term, Crank-Nicolson on the diffusion term and on
///    lap T, and the reaction linearised about p^n and split trapezoidally (n + n'/2 (p' - p)),
///    so that its stiff decay at p = 0 and 1 does not limit dt (the paper's dt 0.0008 exceeds
///    2 tau / |n'| where T is warm). The implicit systems are solved by ImplicitSystem.
/// The melt map (field `melt`, 1 where absent) scales the undercooling locally:
///   T_e(x) = T_inf + melt(x) (T_e - T_inf).
///
/// The per-cell arithmetic lives here as inline functions over flat arrays with precomputed
/// neighbour offsets, so the sparse VDB kernel (per leaf, on a padded block) and the plain
/// dense-array reference loop run literally the same code.
#include <frostvdb/core/Lattice.h>

#include <cmath>
#include <cstddef>
#include <cstdint>

namespace frostvdb {

enum class PhaseFieldScheme { Euler, SecondOrder };

struct KobayashiParams {
    double tau = 0.0003;
    double epsBar = 0.01;
    double delta = 0.1;
    double anisotropyMode = 6.0; ///< j
    double theta0 = M_PI / 2.0;
    double alpha = 0.9;
    double gamma = 10.0;
    double meltTemperature = 1.0; ///< T_e
    double latentHeat = 1.5;      ///< K
    double farTemperature = 0.0;  ///< T_inf: initial and far-field temperature
    double noise = 0.0;           ///< a
    double dt = 0.0002;
    PhaseFieldScheme scheme = PhaseFieldScheme::Euler;
    double solverTolerance = 1e-8; ///< max-norm residual of the implicit systems (second order)
    int solverMaxIterations = 500;
    bool useBiCGSTAB = false;      ///< second order: Eigen BiCGSTAB instead of Gauss-Seidel

    /// T_e at a voxel with melt-map value @a melt.
    double localMeltTemperature(double melt) const
    {
        return farTemperature + melt * (meltTemperature - farTemperature);
    }

    /// Bounds of the reaction's slope dn/dp over p in [0,1] and every m(T) in (-alpha/2, alpha/2)
    /// (plus the noise): the largest growth rate (dn/dp > 0, inside the interface) and the
    /// largest decay rate |dn/dp| (at p = 0 and 1). Sampled finely; n is a cubic in p.
    void reactionSlopeBounds(double& maxGrowth, double& maxDecay) const
    {
        maxGrowth = 0;
        maxDecay = 0;
        const double mMax = 0.5 * std::fabs(alpha) + 0.5 * std::fabs(noise);
        for (double m : {-mMax, 0.0, mMax})
            for (int q = 0; q <= 1000; ++q) {
                const double pp = q / 1000.0, g = pp - 0.5 + m;
                const double dn = (1.0 - 2.0 * pp) * g + pp * (1.0 - pp);
                maxGrowth = std::fmax(maxGrowth, dn);
                maxDecay = std::fmax(maxDecay, -dn);
            }
    }

    /// Largest forward-Euler dt that keeps the update monotone, so p stays within [0, 1] and T
    /// within its sources' bounds: every coefficient of the explicit update stays >= 0, i.e.
    /// dt (eps_max^2 |w0| + max|dn/dp|) <= tau for the phase and dt |w0| <= 1 for the heat
    /// (w0 the Laplacian's centre weight). Taking the terms one by one (diffusion alone, then
    /// reaction alone) is not enough: the stability suite saw p reach 1.016 at that dt.
    double explicitStabilityLimit(const Stencil& s) const
    {
        const double w0 = std::fabs(s.wLapCentre);
        const double epsMax = epsBar * (1.0 + std::fabs(delta));
        double growth, decay;
        reactionSlopeBounds(growth, decay);
        return std::fmin(1.0 / w0, tau / (epsMax * epsMax * w0 + std::fmax(growth, decay)));
    }

    /// Largest stable dt of the second-order scheme. Diffusion (Crank-Nicolson) and the decaying
    /// reaction (trapezoidal) are unconditionally stable; what remains is
    ///  - the Lax-Wendroff advection with velocity grad(eps^2)/tau: dt |v|_1 / h <= 1, where each
    ///    gradient component of eps^2 is at most (eps_max^2 - eps_min^2)/h, so
    ///    |v|_1 <= d (eps_max^2 - eps_min^2)/(h tau), d the number of independent directions;
    ///  - the growing reaction inside the interface, whose trapezoidal factor (1 + r n'/2) /
    ///    (1 - r n'/2), r = dt/tau, overshoots p's bounds once r n' > 1: dt <= tau / max n'.
    double secondOrderStabilityLimit(const Stencil& s, bool withZ) const
    {
        const double epsMax = epsBar * (1.0 + std::fabs(delta)), epsMin = epsBar * std::fmax(0.0, 1.0 - std::fabs(delta));
        const double dAlpha = epsMax * epsMax - epsMin * epsMin;
        double limit = 1e30;
        if (dAlpha > 0) limit = tau * s.spacing * s.spacing / ((withZ ? 3.0 : 2.0) * dAlpha);
        double growth, decay;
        reactionSlopeBounds(growth, decay);
        if (growth > 0) limit = std::fmin(limit, tau / growth);
        return limit;
    }

    double stabilityLimit(const Stencil& s, bool withZ) const
    {
        return scheme == PhaseFieldScheme::Euler ? explicitStabilityLimit(s) : secondOrderStabilityLimit(s, withZ);
    }
};

/// A stencil flattened for one array layout: neighbour k of cell i is at i + off[k].
struct FlatStencil {
    static constexpr int kMaxTaps = 8;
    int n = 0;
    std::ptrdiff_t off[kMaxTaps];
    double ex[kMaxTaps], ey[kMaxTaps], ez[kMaxTaps], wGrad[kMaxTaps], wLap[kMaxTaps];
    double invH2 = 1;       ///< 1/h^2: weight of a directional second difference
    bool hexagonal = false; ///< in-plane taps are the 3 hexagonal directions
    double wLapSum = 0;     ///< -(centre weight of the Laplacian)

    /// @a strideY, @a strideZ: distance between rows and slices of the layout.
    FlatStencil(const Stencil& s, std::ptrdiff_t strideY, std::ptrdiff_t strideZ)
    {
        for (const auto& t : s.taps) {
            off[n] = t.offset.x() + t.offset.y() * strideY + t.offset.z() * strideZ;
            ex[n] = t.ex;
            ey[n] = t.ey;
            ez[n] = t.ez;
            wGrad[n] = t.wGrad;
            wLap[n] = t.wLap;
            ++n;
        }
        invH2 = 1.0 / (s.spacing * s.spacing);
        hexagonal = s.hexagonal;
        wLapSum = -s.wLapCentre;
    }
};

/// Precomputed per-run constants of the anisotropy.
struct Anisotropy {
    double epsBar, delta, j, theta0, cj0, sj0;
    int integerMode; ///< j as an integer >= 0, or -1 when j is fractional
    explicit Anisotropy(const KobayashiParams& k)
        : epsBar(k.epsBar), delta(k.delta), j(k.anisotropyMode), theta0(k.theta0),
          cj0(std::cos(k.anisotropyMode * k.theta0)), sj0(std::sin(k.anisotropyMode * k.theta0)),
          integerMode(std::floor(k.anisotropyMode) == k.anisotropyMode ? int(k.anisotropyMode) : -1)
    {
    }

    /// eps(theta) and d eps / d theta for the gradient direction (gx, gy). Integer j avoids
    /// trigonometry: e^{i j theta} is the j-th power of the unit gradient as a complex number.
    inline void operator()(double gx, double gy, double& eps, double& epsPrime) const
    {
        double c, s; // cos and sin of j (theta0 - theta)
        if (integerMode >= 0) {
            double wr = 1.0, wi = 0.0;
            const double r2 = gx * gx + gy * gy;
            if (r2 > 1e-30) {
                const double inv = 1.0 / std::sqrt(r2);
                const double zr = gx * inv, zi = gy * inv;
                for (int q = 0; q < integerMode; ++q) {
                    const double t = wr * zr - wi * zi;
                    wi = wr * zi + wi * zr;
                    wr = t;
                }
            }
            c = cj0 * wr + sj0 * wi;
            s = sj0 * wr - cj0 * wi;
        } else {
            const double theta = std::atan2(gy, gx);
            c = std::cos(j * (theta0 - theta));
            s = std::sin(j * (theta0 - theta));
        }
        eps = epsBar * (1.0 + delta * c);
        epsPrime = epsBar * delta * j * s;
    }
};

/// Pass 1 at cell i: the gradient of p and the anisotropic coefficients the update needs at
/// the neighbours: a = eps^2, cx = eps eps' p_x, cy = eps eps' p_y.
inline void kobayashiAux(const float* p, std::size_t i, const FlatStencil& st, const Anisotropy& an,
                         float* a, float* cx, float* cy, float* gx, float* gy, float* gz)
{
    const double p0 = p[i];
    double sx = 0, sy = 0, sz = 0;
    for (int q = 0; q < st.n; ++q) {
        const double d = st.wGrad[q] * (double(p[i + st.off[q]]) - p0);
        sx += d * st.ex[q];
        sy += d * st.ey[q];
        sz += d * st.ez[q];
    }
    double eps, epsPrime;
    an(sx, sy, eps, epsPrime);
    a[i] = float(eps * eps);
    cx[i] = float(eps * epsPrime * sx);
    cy[i] = float(eps * epsPrime * sy);
    gx[i] = float(sx);
    gy[i] = float(sy);
    gz[i] = float(sz);
}

/// Pass 2 at cell i: forward-Euler update of p and T (eqs. 1-2). @a Te is the local melt
/// temperature, @a chi the noise draw in [-1/2, 1/2] (ignored when noise is 0). Returns dp.
inline double kobayashiEuler(const float* p, const float* T, const float* a, const float* cx, const float* cy,
                             const float* gx, const float* gy, const float* gz, std::size_t i,
                             const FlatStencil& st, const KobayashiParams& k, double Te, double chi,
                             float& pOut, float& tOut)
{
    const double p0 = p[i], t0 = T[i], a0 = a[i], cx0 = cx[i], cy0 = cy[i];
    double lapP = 0, lapT = 0, dax = 0, day = 0, daz = 0, cross = 0;
    for (int q = 0; q < st.n; ++q) {
        const std::size_t j = i + st.off[q];
        lapP += st.wLap[q] * (double(p[j]) - p0);
        lapT += st.wLap[q] * (double(T[j]) - t0);
        const double da = st.wGrad[q] * (double(a[j]) - a0);
        dax += da * st.ex[q];
        day += da * st.ey[q];
        daz += da * st.ez[q];
        cross += st.wGrad[q] * (-st.ex[q] * (double(cy[j]) - cy0) + st.ey[q] * (double(cx[j]) - cx0));
    }
    const double div = a0 * lapP + dax * gx[i] + day * gy[i] + daz * gz[i];
    const double m = k.alpha / M_PI * std::atan(k.gamma * (Te - t0));
    const double reaction = p0 * (1.0 - p0) * (p0 - 0.5 + m + k.noise * chi);
    const double dp = k.dt / k.tau * (div + cross + reaction);
    pOut = float(p0 + dp);
    tOut = float(t0 + k.dt * lapT + k.latentHeat * dp);
    return dp;
}

/// kobayashiEuler at a cell whose p is exactly 0 at every cell within two stencil steps (the
/// whole neighbourhood pass 1 and 2 read): there the anisotropy coefficients are constants, every
/// term of dp is an exact zero, so p stays 0 and T takes the plain heat step; the same
/// operations in the same order give the same bits. Keep in step with kobayashiEuler's T update.
inline void kobayashiEulerHeatOnly(const float* T, std::size_t i, const FlatStencil& st, const KobayashiParams& k,
                                   float& pOut, float& tOut)
{
    const double t0 = T[i];
    double lapT = 0;
    for (int q = 0; q < st.n; ++q) lapT += st.wLap[q] * (double(T[i + st.off[q]]) - t0);
    const double dp = 0.0;
    pOut = 0.f;
    tOut = float(t0 + k.dt * lapT + k.latentHeat * dp);
}

/// c^T H(u) c at cell i from the lattice's directional second differences
/// D_k = (u(+e_k) - 2 u + u(-e_k)) / h^2: sum_k (c.e_k)^2 D_k on the square lattice (the
/// paper's per-axis Lax-Wendroff form: exact when u_xy = 0), and on the hexagonal lattice
/// sum_k (4/3 (c.e_k)^2 - 1/3 |c|^2) D_k over its three directions, exact for every quadratic
/// (from sum_k e_k e_k^T = 3/2 I and sum_k (c.e_k)^2 e_k e_k^T = 3/8 (|c|^2 I + 2 c c^T)).
inline double directionalSecondDerivative(const float* u, std::size_t i, const FlatStencil& st, double cx, double cy,
                                          double cz)
{
    const double u0 = u[i];
    const double cxy2 = cx * cx + cy * cy;
    double sum = 0;
    for (int q = 0; q < st.n; ++q) {
        const double ce = cx * st.ex[q] + cy * st.ey[q] + cz * st.ez[q];
        const bool inPlane = st.ez[q] == 0.0;
        const double w = (st.hexagonal && inPlane) ? (4.0 / 3.0) * ce * ce - (1.0 / 3.0) * cxy2 : ce * ce;
        sum += w * (double(u[i + st.off[q]]) - u0);
    }
    return sum * st.invH2;
}

/// The explicit parts of one second-order step at cell i (eq. 8), for the implicit system
///   (1 + r/2 a W - r/2 n') p' - r/2 a sum_q w_q p'_q = rhs,   r = dt/tau, a = eps^2,
/// returned as diag, scale (= r/2 a) and rhs; @a predictor (fully explicit) is the solver's
/// first guess. Coefficients (a, its gradient c, m(T), n') are taken at the step's midpoint,
/// extrapolated from the last two steps (pe = 3/2 p^n - 1/2 p^{n-1}, the same for T), which
/// keeps the scheme second order in time although they depend on the solution; @a a holds
/// eps^2 of pe (kobayashiAux on pe). Lax-Wendroff on the advection with velocity c/tau:
///   increment = r [c . grad p^n + dt/(2 tau) c^T H(p^n) c],
/// c^T H c from the lattice's directional second differences D_k: sum_k (c.e_k)^2 D_k on the
/// square lattice (the paper's per-axis form), and on the hexagonal one the exact
/// sum_k (4/3 (c.e_k)^2 - 1/3 |c|^2) D_k over its three directions. The reaction is
/// n(pe) + n'(pe) ((p^n + p')/2 - pe): linearised about the midpoint, trapezoidal in p.
/// The full Lax-Wendroff correction also advects the other terms: + dt/(2 tau) c . grad f with
/// f = eps^2 lap p + n (kobayashiNonAdvective, precomputed on the block). Also returns lap T^n
/// for the temperature system.
struct SecondOrderRow {
    double diag, scale, rhs, predictor, lapT;
};

/// The rest of the phase equation's right-hand side at cell i, f = eps^2 lap p + n(p, T), for
/// the Lax-Wendroff cross term c . grad f (see kobayashiSecondOrderRow).
inline double kobayashiNonAdvective(const float* p, const float* T, const float* a, std::size_t i,
                                    const FlatStencil& st, const KobayashiParams& k, double Te)
{
    const double p0 = p[i];
    double lapP = 0;
    for (int q = 0; q < st.n; ++q) lapP += st.wLap[q] * (double(p[i + st.off[q]]) - p0);
    const double m = k.alpha / M_PI * std::atan(k.gamma * (Te - double(T[i])));
    return double(a[i]) * lapP + p0 * (1.0 - p0) * (p0 - 0.5 + m);
}

inline SecondOrderRow kobayashiSecondOrderRow(const float* p, const float* T, const float* pe, const float* te,
                                              const float* a, const float* f, std::size_t i, const FlatStencil& st,
                                              const KobayashiParams& k, double Te, double chi)
{
    const double p0 = p[i], t0 = T[i], a0 = a[i];
    double lapP = 0, lapT = 0, cx = 0, cy = 0, cz = 0, gx = 0, gy = 0, gz = 0, fx = 0, fy = 0, fz = 0;
    const double f0 = f[i];
    for (int q = 0; q < st.n; ++q) {
        const std::size_t j = i + st.off[q];
        const double dfq = st.wGrad[q] * (double(f[j]) - f0);
        fx += dfq * st.ex[q];
        fy += dfq * st.ey[q];
        fz += dfq * st.ez[q];
        const double dpq = double(p[j]) - p0;
        lapP += st.wLap[q] * dpq;
        lapT += st.wLap[q] * (double(T[j]) - t0);
        gx += st.wGrad[q] * dpq * st.ex[q];
        gy += st.wGrad[q] * dpq * st.ey[q];
        gz += st.wGrad[q] * dpq * st.ez[q];
        const double da = st.wGrad[q] * (double(a[j]) - a0);
        cx += da * st.ex[q];
        cy += da * st.ey[q];
        cz += da * st.ez[q];
    }
    const double cHc = directionalSecondDerivative(p, i, st, cx, cy, cz);
    const double r = k.dt / k.tau;
    const double pm = pe[i];
    const double m = k.alpha / M_PI * std::atan(k.gamma * (Te - double(te[i])));
    const double g = pm - 0.5 + m + k.noise * chi;
    const double nm = pm * (1.0 - pm) * g;
    // dn/dp at the midpoint; below the stability limit r dn <= 1, so diag stays >= 1/2.
    const double dn = (1.0 - 2.0 * pm) * g + pm * (1.0 - pm);
    // Lax-Wendroff on tau p_t = c . grad p + f: p_tt ~ (c/tau) . grad(p_t) = (c . grad(c . grad p)
    // + c . grad f) / tau^2 with c frozen at the midpoint. The paper keeps only the first part;
    // the second (the advection of diffusion and reaction) is what makes the step second order
    // when the anisotropy moves the front (docs/accuracy.md).
    const double advection = cx * gx + cy * gy + cz * gz + 0.5 * k.dt / k.tau * (cHc + cx * fx + cy * fy + cz * fz);
    SecondOrderRow row;
    row.scale = 0.5 * r * a0;
    row.diag = 1.0 + row.scale * st.wLapSum - 0.5 * r * dn;
    row.rhs = p0 + r * (advection + 0.5 * a0 * lapP + nm + dn * (0.5 * p0 - pm));
    row.predictor = p0 + r * (advection + a0 * lapP + nm + dn * (p0 - pm));
    row.lapT = lapT;
    return row;
}

} // namespace frostvdb
