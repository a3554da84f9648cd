// BRDF Moments: shared OSL code for the preview shaders (see the .osl files).
//
// Conventions (SPEC §3): local frame z = normal, the view in the xz-plane at +x;
// view-centred angles m(theta, phi) = (sin t cos p, sin p, cos t cos p); the moment
// measure is d theta d phi and solid angle is cos(phi) d theta d phi, so a direction
// sampled with density q(theta, phi) adds f L cos(t) cos(p)^2 / q.
// Environment: Blender's world mapping, u = 0.5 - atan2(y, x) / 2pi, OIIO t from the top row.

#define BM_HALF_PI 1.5707963267948966
#define BM_PI 3.141592653589793
#define BM_SQRT2 1.4142135623730951
#define BM_SQRT_2PI 2.5066282746310002
#define BM_MAX_S 20.0
#define BM_CAP_FRACTION 0.995

float bm_cdf(float x) { return 0.5 * erfc(-x / BM_SQRT2); }

// Inverse standard normal CDF (P. J. Acklam's rational approximation, rel. error 1.2e-9).
float bm_quantile(float p_in)
{
    float p = clamp(p_in, 1e-30, 1.0 - 1e-7);
    float a1 = -3.969683028665376e+01, a2 = 2.209460984245205e+02, a3 = -2.759285104469687e+02;
    float a4 = 1.383577518672690e+02, a5 = -3.066479806614716e+01, a6 = 2.506628277459239e+00;
    float b1 = -5.447609879822406e+01, b2 = 1.615858368580409e+02, b3 = -1.556989798598866e+02;
    float b4 = 6.680131188771972e+01, b5 = -1.328068155288572e+01;
    float c1 = -7.784894002430293e-03, c2 = -3.223964580411365e-01, c3 = -2.400758277161838e+00;
    float c4 = -2.549732539343734e+00, c5 = 4.374664141464968e+00, c6 = 2.938163982698783e+00;
    float d1 = 7.784695709041462e-03, d2 = 3.224671290700398e-01, d3 = 2.445134137142996e+00;
    float d4 = 3.754408661907416e+00;
    if (p < 0.02425) {
        float q = sqrt(-2.0 * log(p));
        return (((((c1 * q + c2) * q + c3) * q + c4) * q + c5) * q + c6) / ((((d1 * q + d2) * q + d3) * q + d4) * q + 1.0);
    }
    if (p > 1.0 - 0.02425) {
        float q = sqrt(-2.0 * log(1.0 - p));
        return -(((((c1 * q + c2) * q + c3) * q + c4) * q + c5) * q + c6) / ((((d1 * q + d2) * q + d3) * q + d4) * q + 1.0);
    }
    float q = p - 0.5;
    float r = q * q;
    return (((((a1 * r + a2) * r + a3) * r + a4) * r + a5) * r + a6) * q / (((((b1 * r + b2) * r + b3) * r + b4) * r + b5) * r + 1.0);
}

// Standardized bounds of [-pi/2, pi/2], mirrored when the interval lies mostly above the mean
// (the CDF keeps its precision in the lower tail).
void bm_bounds(float m, float s, output float lo, output float hi, output float flip)
{
    float a = (-BM_HALF_PI - m) / s, b = (BM_HALF_PI - m) / s;
    flip = (a + b > 0.0) ? -1.0 : 1.0;
    lo = (flip < 0.0) ? -b : a;
    hi = (flip < 0.0) ? -a : b;
}

float bm_mass(float m, float s)
{
    float lo, hi, flip;
    bm_bounds(m, s, lo, hi, flip);
    return max(bm_cdf(hi) - bm_cdf(lo), 1e-30);
}

float bm_tn_pdf(float x, float m, float s)
{
    if (abs(x) > BM_HALF_PI) return 0.0;
    float z = (x - m) / s;
    return exp(-0.5 * z * z) / (s * BM_SQRT_2PI * bm_mass(m, s));
}

float bm_tn_sample(float m, float s, float u)
{
    float lo, hi, flip;
    bm_bounds(m, s, lo, hi, flip);
    float plo = bm_cdf(lo), phi_ = bm_cdf(hi);
    float z = clamp(bm_quantile(plo + u * (phi_ - plo)), lo, hi);
    return clamp(m + flip * s * z, -BM_HALF_PI, BM_HALF_PI);
}

// Moments of z = (x - m)/s for x ~ N(m, s^2) truncated to [-pi/2, pi/2]: mean, central
// c2, c3, c4, and raw E[z^3].
void bm_z_moments(float m, float s, output float mu, output float c2, output float c3, output float c4,
                  output float m3)
{
    float a = (-BM_HALF_PI - m) / s, b = (BM_HALF_PI - m) / s;
    float z = bm_mass(m, s);
    float pa = exp(-0.5 * a * a) / BM_SQRT_2PI, pb = exp(-0.5 * b * b) / BM_SQRT_2PI;
    float m1 = (pa - pb) / z;
    float m2 = 1.0 + (a * pa - b * pb) / z;
    m3 = 2.0 * m1 + (a * a * pa - b * b * pb) / z;
    float m4 = 3.0 * m2 + (a * a * a * pa - b * b * b * pb) / z;
    mu = m1;
    c2 = max(m2 - m1 * m1, 1e-30);
    c3 = m3 - 3.0 * m1 * m2 + 2.0 * m1 * m1 * m1;
    c4 = m4 - 4.0 * m1 * m3 + 6.0 * m1 * m1 * m2 - 3.0 * m1 * m1 * m1 * m1;
}

// The largest variance a truncated Gaussian with this mean approaches: the truncated
// exponential's, 1/u^2 - 1/sinh(u)^2 (times h^2) with coth(u) - 1/u = mean / h (bisection).
// core/fits/truncated.py variance_cap.
float bm_variance_cap(float mean)
{
    float mu = clamp(mean / BM_HALF_PI, -1.0, 1.0);
    if (abs(mu) >= 1.0) return 0.0;
    float lo = -1e4, hi = 1e4;
    for (int i = 0; i < 60; i++) {
        float u = 0.5 * (lo + hi);
        float mean_u = abs(u) < 1e-3 ? u / 3.0 - u * u * u / 45.0 : 1.0 / tanh(u) - 1.0 / u;
        if (mean_u < mu) lo = u; else hi = u;
    }
    float u = 0.5 * (lo + hi);
    float v;
    if (abs(u) < 1e-2) v = 1.0 / 3.0 - u * u / 15.0 + 2.0 * u * u * u * u / 189.0;
    else if (abs(u) > 80.0) v = 1.0 / (u * u);
    else { float sh = sinh(u); v = 1.0 / (u * u) - 1.0 / (sh * sh); }
    return max(v, 0.0) * BM_HALF_PI * BM_HALF_PI;
}

// (m, s) of the Gaussian whose truncation to [-pi/2, pi/2] has this mean and variance, by the
// engine's one rule (core/fits/truncated.py solve): the mean kept, the variance capped at
// BM_CAP_FRACTION of bm_variance_cap; then Newton in (m, log s) on the scaled residuals, exact
// Jacobian, step halving; s in [1e-4, BM_MAX_S], m steps bounded by 0.5 + 4 s.
void bm_truncated_params(float mean_in, float var_in, output float m, output float s)
{
    float mean = clamp(mean_in, -BM_HALF_PI * 0.9999999, BM_HALF_PI * 0.9999999);
    float var = max(min(var_in, BM_CAP_FRACTION * bm_variance_cap(mean)), 1e-14);
    float sd = sqrt(var);
    float lo = log(1e-4), hi = log(BM_MAX_S);
    float ls = clamp(log(sd), lo, hi);
    m = mean;
    s = exp(ls);
    float mu, c2, c3, c4, m3;
    bm_z_moments(m, s, mu, c2, c3, c4, m3);
    float r1 = (m + s * mu - mean) / sd, r2 = log(s * s * c2 / var);
    for (int it = 0; it < 40; it++) {
        float norm = r1 * r1 + r2 * r2;
        if (norm < 1e-12) break;
        float j11 = c2 / sd, j12 = s * (m3 - mu * (c2 + mu * mu)) / sd;
        float j21 = c3 / (s * c2), j22 = (c4 - c2 * c2 + 2.0 * mu * c3) / c2;
        float det = j11 * j22 - j12 * j21;
        float dm, dl;
        if (abs(det) > 1e-30) {
            dm = -(j22 * r1 - j12 * r2) / det;
            dl = -(-j21 * r1 + j11 * r2) / det;
        } else {
            dm = -r1 / max(j11, 1e-30);
            dl = 0.0;
        }
        dm = clamp(dm, -0.5 - 4.0 * s, 0.5 + 4.0 * s);
        dl = clamp(dl, -1.0, 1.0);
        float step = 1.0;
        for (int h = 0; h < 6; h++) {
            float nm = clamp(m + step * dm, -1e4, 1e4);
            float nl = clamp(ls + step * dl, lo, hi);
            float ns = exp(nl);
            float nmu, nc2, nc3, nc4, nm3;
            bm_z_moments(nm, ns, nmu, nc2, nc3, nc4, nm3);
            float q1 = (nm + ns * nmu - mean) / sd, q2 = log(ns * ns * nc2 / var);
            if (q1 * q1 + q2 * q2 < norm || h == 5) {
                m = nm; ls = nl; s = ns;
                mu = nmu; c2 = nc2; c3 = nc3; c4 = nc4; m3 = nm3;
                r1 = q1; r2 = q2;
                break;
            }
            step *= 0.5;
        }
    }
}

// Sec. 3.4 energy curve, per channel.
color bm_energy(float t, color alpha_b, float theta0, float theta1, color alpha1, color m1)
{
    if (t <= theta0) return alpha_b;
    if (t > theta1) return alpha1 + m1 * (t - theta1);
    float span = max(theta1 - theta0, 1e-6);
    float s = (t - theta0) / span;
    float h00 = 2.0 * s * s * s - 3.0 * s * s + 1.0;
    float h01 = -2.0 * s * s * s + 3.0 * s * s;
    float h11 = (s * s * s - s * s) * span;
    return h00 * alpha_b + h01 * alpha1 + h11 * m1;
}

// Radiance around d averaged over about `footprint` steradians (0: the texel itself): the
// texture's MIP levels through OIIO's filter, sized by derivatives in (s, t). Each of N
// samples stands for 1 / (N q) sr of the lobe (filtered importance sampling), so a small
// bright light seen by few samples is spread over their footprints instead of flickering.
color bm_environment(string map, vector d, float footprint)
{
    float u = 0.5 - atan2(d[1], d[0]) / (2.0 * BM_PI);
    u = u - floor(u);
    float z = clamp(d[2], -1.0, 1.0);
    float t = 0.5 - asin(z) / BM_PI;
    if (footprint <= 0.0)
        return (color) texture(map, u, t, 0, 0, 0, 0, "interp", "closest", "swrap", "periodic", "twrap", "clamp");
    float r = sqrt(footprint);
    float ds = min(r / (2.0 * BM_PI * max(sqrt(max(1.0 - z * z, 0.0)), 0.02)), 0.5);
    float dt = min(r / BM_PI, 0.5);
    return (color) texture(map, u, t, ds, 0, 0, dt, "interp", "linear", "swrap", "periodic", "twrap", "clamp");
}

// The shading frame: the true sphere normal (from the object-space position, not the mesh's
// facets), the view I (toward the viewer in Cycles), tangent T toward the view.
void bm_frame(output vector Nw, output vector T, output vector B, output float theta_o)
{
    vector po = vector(transform("object", P));
    Nw = normalize(transform("object", "world", normalize(po)));
    vector V = normalize(I);
    float c = dot(Nw, V);
    vector t = V - c * Nw;
    if (length(t) < 1e-6) {
        t = cross(Nw, vector(0, 0, 1));
        if (length(t) < 1e-6) t = cross(Nw, vector(1, 0, 0));
    }
    T = normalize(t);
    B = cross(Nw, T);
    theta_o = acos(clamp(c, 0.0, 1.0));
}

vector bm_direction(float theta, float phi, vector T, vector B, vector Nw)
{
    float cp = cos(phi);
    return sin(theta) * cp * T + sin(phi) * B + cos(theta) * cp * Nw;
}

// Low-discrepancy pair k of a per-shading-point rotated R2 sequence.
void bm_r2(int k, float o1, float o2, output float u1, output float u2)
{
    float v1 = o1 + 0.7548776662466927 * k;
    float v2 = o2 + 0.5698402909980532 * k;
    u1 = v1 - floor(v1);
    u2 = v2 - floor(v2);
}
