/* A minimal point-to-point ICP in C that follows pcreg's cmd: file protocol, for cross-checks.
 *
 *   cc -O2 -o icp_min tools/icp_min.c -lm
 *   pcreg crosscheck target.npy source.npy --with 'reference,cmd:"./icp_min {source} {target} {init} {out} {params}"'
 *
 * Reads {source} and {target} (.npy, (N, d) float64 little-endian, C order, d = 2 or 3), {init} (a
 * (d+1)x(d+1) text matrix) and {params} (JSON: max_correspondence_distance, max_iterations,
 * relative_fitness, relative_rmse); writes {out} (the (d+1)x(d+1) matrix T_target_source) and
 * {out}.json (iterations, fitness, inlier_rmse, converged).
 *
 * The algorithm is the reference's: exact nearest neighbours within the distance (brute force), the
 * least-squares rigid update in closed form (2-D: the angle atan2(c - b, a + d) of the cross-covariance;
 * 3-D: Horn's unit quaternion, the top eigenvector of his 4x4 matrix, by Jacobi rotations), and Open3D's
 * stopping rule. With a trailing --wrong it transposes every rotation update: a deliberately wrong ICP.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void die(const char *msg, const char *arg) {
    fprintf(stderr, "icp_min: %s%s%s\n", msg, arg ? ": " : "", arg ? arg : "");
    exit(1);
}

static double *read_npy(const char *path, long *n, int *d) {
    FILE *f = fopen(path, "rb");
    if (!f) die("cannot open", path);
    unsigned char head[10];
    if (fread(head, 1, 10, f) != 10 || memcmp(head, "\x93NUMPY", 6) != 0) die("not a .npy file", path);
    long hlen;
    if (head[6] == 1) {
        hlen = head[8] | (head[9] << 8);
    } else {
        unsigned char more[2];
        if (fread(more, 1, 2, f) != 2) die("truncated header", path);
        hlen = head[8] | (head[9] << 8) | ((long)more[0] << 16) | ((long)more[1] << 24);
    }
    char *h = malloc(hlen + 1);
    if (fread(h, 1, hlen, f) != (size_t)hlen) die("truncated header", path);
    h[hlen] = 0;
    if (!strstr(h, "'<f8'") || strstr(h, "'fortran_order': True")) die("expected '<f8' C-order data", path);
    char *s = strstr(h, "'shape': (");
    if (!s || sscanf(s + 10, "%ld, %d", n, d) != 2 || *n < 1 || (*d != 2 && *d != 3)) die("expected shape (N, 2|3)", path);
    free(h);
    double *p = malloc(sizeof(double) * (*n) * (*d));
    if (fread(p, sizeof(double), (*n) * (*d), f) != (size_t)((*n) * (*d))) die("truncated data", path);
    fclose(f);
    return p;
}

static double json_number(const char *text, const char *key) {
    char pat[64];
    snprintf(pat, sizeof pat, "\"%s\"", key);
    const char *s = strstr(text, pat);
    if (!s) die("missing parameter", key);
    s = strchr(s + strlen(pat), ':');
    if (!s) die("bad parameter", key);
    return strtod(s + 1, NULL);
}

/* Symmetric 4x4 eigenvector of the largest eigenvalue by cyclic Jacobi. */
static void top_eigenvector(double A[4][4], double v[4]) {
    double V[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
    for (int sweep = 0; sweep < 100; sweep++) {
        double off = 0;
        for (int p = 0; p < 4; p++)
            for (int q = p + 1; q < 4; q++) off += A[p][q] * A[p][q];
        if (off < 1e-300) break;
        for (int p = 0; p < 4; p++)
            for (int q = p + 1; q < 4; q++) {
                if (fabs(A[p][q]) < 1e-300) continue;
                double theta = (A[q][q] - A[p][p]) / (2 * A[p][q]);
                double t = (theta >= 0 ? 1 : -1) / (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1 / sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < 4; k++) {
                    double akp = A[k][p], akq = A[k][q];
                    A[k][p] = c * akp - s * akq;
                    A[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 4; k++) {
                    double apk = A[p][k], aqk = A[q][k];
                    A[p][k] = c * apk - s * aqk;
                    A[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 4; k++) {
                    double vkp = V[k][p], vkq = V[k][q];
                    V[k][p] = c * vkp - s * vkq;
                    V[k][q] = s * vkp + c * vkq;
                }
            }
    }
    int best = 0;
    for (int i = 1; i < 4; i++)
        if (A[i][i] > A[best][best]) best = i;
    for (int i = 0; i < 4; i++) v[i] = V[i][best];
}

int main(int argc, char **argv) {
    if (argc < 6) die("usage: icp_min SOURCE.npy TARGET.npy INIT.txt OUT.txt PARAMS.json [--wrong]", NULL);
    int wrong = argc > 6 && strcmp(argv[6], "--wrong") == 0;
    long n, m;
    int d, d2;
    double *src = read_npy(argv[1], &n, &d);
    double *tgt = read_npy(argv[2], &m, &d2);
    if (d != d2) die("source and target differ in dimension", NULL);
    int D = d + 1;
    double T[4][4] = {{0}};
    FILE *f = fopen(argv[3], "r");
    if (!f) die("cannot open", argv[3]);
    for (int i = 0; i < D; i++)
        for (int j = 0; j < D; j++)
            if (fscanf(f, "%lf", &T[i][j]) != 1) die("bad initial matrix", argv[3]);
    fclose(f);
    f = fopen(argv[5], "r");
    if (!f) die("cannot open", argv[5]);
    char text[4096];
    size_t len = fread(text, 1, sizeof text - 1, f);
    text[len] = 0;
    fclose(f);
    double gate = json_number(text, "max_correspondence_distance");
    int max_it = (int)json_number(text, "max_iterations");
    double rel_fit = json_number(text, "relative_fitness"), rel_rmse = json_number(text, "relative_rmse");

    double *pts = malloc(sizeof(double) * n * d);
    long *idx = malloc(sizeof(long) * n);
    double *dist = malloc(sizeof(double) * n);
    for (long i = 0; i < n; i++)
        for (int a = 0; a < d; a++) {
            double v = T[a][d];
            for (int b = 0; b < d; b++) v += T[a][b] * src[i * d + b];
            pts[i * d + a] = v;
        }
    double fitness = 0, rmse = 0;
    int iterations = 0, converged = 0;
    for (int it = 0; it <= max_it; it++) {
        /* correspondences and score at the current pose */
        long k = 0;
        double sq = 0;
        for (long i = 0; i < n; i++) {
            double best = INFINITY;
            long bj = -1;
            for (long j = 0; j < m; j++) {
                double s = 0;
                for (int a = 0; a < d; a++) {
                    double e = pts[i * d + a] - tgt[j * d + a];
                    s += e * e;
                }
                if (s < best) { best = s; bj = j; }
            }
            if (sqrt(best) < gate) { idx[i] = bj; dist[i] = best; k++; sq += best; } else idx[i] = -1;
        }
        double prev_fit = fitness, prev_rmse = rmse;
        fitness = (double)k / n;
        rmse = k ? sqrt(sq / k) : 0;
        if (it > 0 && fabs(prev_fit - fitness) < rel_fit && fabs(prev_rmse - rmse) < rel_rmse) { converged = 1; break; }
        if (it == max_it) break;
        /* closed-form update from the correspondences */
        double U[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
        if (k >= (d == 2 ? 2 : 3)) {
            double mp[3] = {0}, mq[3] = {0}, C[3][3] = {{0}};
            for (long i = 0; i < n; i++)
                if (idx[i] >= 0)
                    for (int a = 0; a < d; a++) { mp[a] += pts[i * d + a]; mq[a] += tgt[idx[i] * d + a]; }
            for (int a = 0; a < d; a++) { mp[a] /= k; mq[a] /= k; }
            /* C[a][b] = sum (p - mp)_a (q - mq)_b / k */
            for (long i = 0; i < n; i++)
                if (idx[i] >= 0)
                    for (int a = 0; a < d; a++)
                        for (int b = 0; b < d; b++)
                            C[a][b] += (pts[i * d + a] - mp[a]) * (tgt[idx[i] * d + b] - mq[b]);
            double R[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
            if (d == 2) {
                double th = atan2(C[0][1] - C[1][0], C[0][0] + C[1][1]);
                R[0][0] = cos(th); R[0][1] = -sin(th); R[1][0] = sin(th); R[1][1] = cos(th);
            } else {
                double Sxx = C[0][0], Sxy = C[0][1], Sxz = C[0][2], Syx = C[1][0], Syy = C[1][1], Syz = C[1][2],
                       Szx = C[2][0], Szy = C[2][1], Szz = C[2][2];
                double N[4][4] = {{Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx},
                                  {Syz - Szy, Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz},
                                  {Szx - Sxz, Sxy + Syx, -Sxx + Syy - Szz, Syz + Szy},
                                  {Sxy - Syx, Szx + Sxz, Syz + Szy, -Sxx - Syy + Szz}};
                double q[4];
                top_eigenvector(N, q);
                double q0 = q[0], qx = q[1], qy = q[2], qz = q[3];
                R[0][0] = q0 * q0 + qx * qx - qy * qy - qz * qz; R[0][1] = 2 * (qx * qy - q0 * qz); R[0][2] = 2 * (qx * qz + q0 * qy);
                R[1][0] = 2 * (qy * qx + q0 * qz); R[1][1] = q0 * q0 - qx * qx + qy * qy - qz * qz; R[1][2] = 2 * (qy * qz - q0 * qx);
                R[2][0] = 2 * (qz * qx - q0 * qy); R[2][1] = 2 * (qz * qy + q0 * qx); R[2][2] = q0 * q0 - qx * qx - qy * qy + qz * qz;
            }
            if (wrong)
                for (int a = 0; a < d; a++)
                    for (int b = a + 1; b < d; b++) { double t = R[a][b]; R[a][b] = R[b][a]; R[b][a] = t; }
            for (int a = 0; a < d; a++) {
                double t = mq[a];
                for (int b = 0; b < d; b++) { U[a][b] = R[a][b]; t -= R[a][b] * mp[b]; }
                U[a][d] = t;
            }
        }
        double NT[4][4] = {{0}};
        for (int a = 0; a < D; a++)
            for (int b = 0; b < D; b++)
                for (int c = 0; c < D; c++) NT[a][b] += U[a][c] * T[c][b];
        memcpy(T, NT, sizeof T);
        for (long i = 0; i < n; i++) {
            double p[3];
            for (int a = 0; a < d; a++) {
                p[a] = U[a][d];
                for (int b = 0; b < d; b++) p[a] += U[a][b] * pts[i * d + b];
            }
            for (int a = 0; a < d; a++) pts[i * d + a] = p[a];
        }
        iterations = it + 1;
    }
    f = fopen(argv[4], "w");
    if (!f) die("cannot write", argv[4]);
    for (int i = 0; i < D; i++)
        for (int j = 0; j < D; j++) fprintf(f, "%.17g%c", T[i][j], j + 1 < D ? ' ' : '\n');
    fclose(f);
    char side[4096];
    snprintf(side, sizeof side, "%s.json", argv[4]);
    f = fopen(side, "w");
    if (!f) die("cannot write", side);
    fprintf(f, "{\"iterations\": %d, \"fitness\": %.17g, \"inlier_rmse\": %.17g, \"converged\": %s}\n", iterations,
            fitness, rmse, converged ? "true" : "false");
    fclose(f);
    return 0;
}
