/* The standard two-link arm's closed-loop step written by hand in C: the reference of
 * benchmarks/backends.py for what one control step can cost on this machine.
 *
 * Thesis Table A.1 (robots/two_link_arm.urdf): m = 1 kg, l = 1 m, centre of mass at l/2,
 * I = m l^2 / 3 about the centre of mass, angles from the horizontal, gravity g along -z.
 * The closed-form planar equations of motion are a benchmark reference only: the library never
 * uses them (benchmarks/backends.py checks them against Pinocchio's RNEA and ABA first).
 *
 * One step: feedforward u_ff = M(q_d) a_d + c(q_d, v_d) + g(q_d); the shoulder tracks q_d, the
 * elbow holds q1 + q2 = pi/2 (PD); u = u_ff + u_fb; a = M(q)^-1 (u - c(q, v) - g(q));
 * semi-implicit Euler. The cycle's desired trajectory (n samples) repeats.
 */
#include <math.h>

static const double M1 = 1.0, M2 = 1.0, L1 = 1.0, LC = 0.5, I = 1.0 / 3.0;

static void dynamics(const double *q, const double *v, double g, double Mq[3], double b[2]) {
    double c2 = cos(q[1]), s2 = sin(q[1]);
    Mq[0] = 2 * I + M1 * LC * LC + M2 * (L1 * L1 + LC * LC + 2 * L1 * LC * c2);
    Mq[1] = I + M2 * (LC * LC + L1 * LC * c2);
    Mq[2] = I + M2 * LC * LC;
    double h = M2 * L1 * LC * s2;
    double g12 = M2 * LC * g * cos(q[0] + q[1]);
    b[0] = -h * (2 * v[0] * v[1] + v[1] * v[1]) + (M1 * LC + M2 * L1) * g * cos(q[0]) + g12;
    b[1] = h * v[0] * v[0] + g12;
}

/* The inverse model (RNEA) and the forward model (ABA), for the benchmark's check. */
void arm_rnea(const double *q, const double *v, const double *a, double g, double *tau) {
    double Mq[3], b[2];
    dynamics(q, v, g, Mq, b);
    tau[0] = Mq[0] * a[0] + Mq[1] * a[1] + b[0];
    tau[1] = Mq[1] * a[0] + Mq[2] * a[1] + b[1];
}

void arm_aba(const double *q, const double *v, const double *tau, double g, double *a) {
    double Mq[3], b[2];
    dynamics(q, v, g, Mq, b);
    double r0 = tau[0] - b[0], r1 = tau[1] - b[1], det = Mq[0] * Mq[2] - Mq[1] * Mq[1];
    a[0] = (Mq[2] * r0 - Mq[1] * r1) / det;
    a[1] = (Mq[0] * r1 - Mq[1] * r0) / det;
}

/* steps control steps from state x = (q1, q2, v1, v2) (updated in place) along the cycle's
 * desired trajectory D (n samples of q_d, v_d, a_d: 6 per sample); returns the summed |u_fb|. */
double arm_run(long steps, long n, const double *D, double *x, double dt, double g,
               const double *kp, const double *kd, double target) {
    double sum = 0.0;
    for (long k = 0; k < steps; ++k) {
        const double *d = D + 6 * (k % n);
        double uff[2], u[2], a[2];
        arm_rnea(d, d + 2, d + 4, g, uff);
        double fb0 = kp[0] * (d[0] - x[0]) + kd[0] * (d[2] - x[2]);
        double fb1 = kp[1] * (target - x[0] - x[1]) + kd[1] * (-x[2] - x[3]);
        u[0] = uff[0] + fb0;
        u[1] = uff[1] + fb1;
        arm_aba(x, x + 2, u, g, a);
        x[2] += dt * a[0];
        x[3] += dt * a[1];
        x[0] += dt * x[2];
        x[1] += dt * x[3];
        sum += fabs(fb0) + fabs(fb1);
    }
    return sum;
}
