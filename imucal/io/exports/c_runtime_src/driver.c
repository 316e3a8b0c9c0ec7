/* A host program around the runtime, compiled by the tests and the benchmark (not written by
 * the export): driver RATE IN OUT [REPEAT [FIRST]] reads IN, float32 rows (acc_raw[3],
 * gyro_raw[3]); writes OUT, float32 rows (acc[3], gyro[3], gyro_b[3], acc_b[3], acc_k[3]) of
 * the first pass; prints each moment ("moment start end accepted r_x r_y r_z se_x se_y se_z"),
 * the final biases and scales, sizeof the state and the nanoseconds per sample over REPEAT
 * passes (each from imucal_rt_init). FIRST numbers the samples from there (modulo 2^32). */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "imucal_runtime.h"

static void report(const imucal_rt_state *st)
{
    const imucal_rt_moment *m = &st->last;
    printf("moment %u %u %d %.9g %.9g %.9g %.9g %.9g %.9g\n", (unsigned)m->start,
           (unsigned)m->end, (int)m->accepted, m->rate[0], m->rate[1], m->rate[2],
           m->rate_se[0], m->rate_se[1], m->rate_se[2]);
}

int main(int argc, char **argv)
{
    static imucal_rt_state st;
    FILE *f;
    float *in, *out;
    long n, i;
    int r, repeat = argc > 4 ? atoi(argv[4]) : 1;
    unsigned long first = argc > 5 ? strtoul(argv[5], NULL, 10) : 0;
    struct timespec t0, t1;
    double ns;
    if (argc < 4) return 2;
    f = fopen(argv[2], "rb");
    if (!f) return 3;
    fseek(f, 0, SEEK_END);
    n = ftell(f) / (long)(6 * sizeof(float));
    fseek(f, 0, SEEK_SET);
    in = malloc((size_t)n * 6 * sizeof(float));
    out = malloc((size_t)n * 15 * sizeof(float));
    if (!in || !out || fread(in, 6 * sizeof(float), (size_t)n, f) != (size_t)n) return 4;
    fclose(f);
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (r = 0; r < repeat; ++r) {
        if (imucal_rt_init(&st, (float)atof(argv[1])) != 0) return 5;
        st.n = (uint32_t)first;  /* the samples' numbers from there, modulo 2^32 */
        for (i = 0; i < n; ++i) {
            float *o = out + 15 * i;
            if (imucal_rt_step(&st, in + 6 * i, in + 6 * i + 3, o, o + 3) && r == 0) report(&st);
            if (r == 0) {
                o[6] = st.gyro_b[0];
                o[7] = st.gyro_b[1];
                o[8] = st.gyro_b[2];
                o[9] = st.acc_b[0];
                o[10] = st.acc_b[1];
                o[11] = st.acc_b[2];
                o[12] = st.acc_k[0];
                o[13] = st.acc_k[1];
                o[14] = st.acc_k[2];
            }
        }
        if (imucal_rt_finish(&st) && r == 0) report(&st);
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    ns = ((double)(t1.tv_sec - t0.tv_sec) * 1e9 + (double)(t1.tv_nsec - t0.tv_nsec))
         / ((double)n * repeat);
    printf("bias %.9g %.9g %.9g\n", st.gyro_b[0], st.gyro_b[1], st.gyro_b[2]);
    printf("acc_b %.9g %.9g %.9g\n", st.acc_b[0], st.acc_b[1], st.acc_b[2]);
    printf("acc_k %.9g %.9g %.9g\n", st.acc_k[0], st.acc_k[1], st.acc_k[2]);
    printf("acc_choice %d %d\n", (int)st.acc_choice, (int)st.acc_covered);
    printf("sizeof %u\n", (unsigned)sizeof(imucal_rt_state));
    printf("ns_per_sample %.3f\n", ns);
    f = fopen(argv[3], "wb");
    if (!f || fwrite(out, 15 * sizeof(float), (size_t)n, f) != (size_t)n) return 6;
    fclose(f);
    return 0;
}
