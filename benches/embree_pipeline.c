/* The Embree yardstick for whole-process picks (issue 14, BENCHMARKS.md "Whole process: load,
 * build, pick"): what a user would write in C with Embree 3 to answer the same job as
 * `raypick pick --scene MESH.obj --rays RAYS.txt --backend cpu`.
 *
 * It parses the OBJ (`v` and `f` lines; `i`, `i/t`, `i//n`, `i/t/n`; negative indices;
 * polygons fan-triangulated), builds an Embree scene (default build quality, Embree's own
 * threads), reads the ray file (`ox oy oz dx dy dz` per line), traces every ray with
 * `rtcIntersect1` and prints the number of hits, so the work cannot be skipped. Vertices are
 * f32, as Embree requires; parsing uses strtod/strtol from the C library.
 *
 * Build: cc -O2 -o target/embree_pipeline benches/embree_pipeline.c -lembree3
 * (Debian: apt-get install libembree-dev). Run: target/embree_pipeline MESH.obj RAYS.txt
 */
#include <embree3/rtcore.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static char *read_all(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    if (!f) { perror(path); exit(2); }
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    if (!buf || fread(buf, 1, (size_t)n, f) != (size_t)n) { fprintf(stderr, "%s: read failed\n", path); exit(2); }
    buf[n] = 0;
    fclose(f);
    *len = (size_t)n;
    return buf;
}

typedef struct { float *v; size_t nv, cv; unsigned *t; size_t nt, ct; } Mesh;

static void push_vertex(Mesh *m, float x, float y, float z) {
    if (m->nv == m->cv) { m->cv = m->cv ? 2 * m->cv : 1024; m->v = realloc(m->v, m->cv * 3 * sizeof(float)); }
    m->v[3 * m->nv] = x; m->v[3 * m->nv + 1] = y; m->v[3 * m->nv + 2] = z;
    m->nv++;
}

static void push_triangle(Mesh *m, unsigned a, unsigned b, unsigned c) {
    if (m->nt == m->ct) { m->ct = m->ct ? 2 * m->ct : 1024; m->t = realloc(m->t, m->ct * 3 * sizeof(unsigned)); }
    m->t[3 * m->nt] = a; m->t[3 * m->nt + 1] = b; m->t[3 * m->nt + 2] = c;
    m->nt++;
}

static void parse_obj(char *text, Mesh *m) {
    char *p = text;
    while (*p) {
        char *line = p;
        char *end = strchr(p, '\n');
        if (end) { *end = 0; p = end + 1; } else { p += strlen(p); }
        while (*line == ' ' || *line == '\t') line++;
        if (line[0] == 'v' && (line[1] == ' ' || line[1] == '\t')) {
            char *q = line + 2;
            float x = (float)strtod(q, &q), y = (float)strtod(q, &q), z = (float)strtod(q, &q);
            push_vertex(m, x, y, z);
        } else if (line[0] == 'f' && (line[1] == ' ' || line[1] == '\t')) {
            char *q = line + 2;
            long idx[64];
            int n = 0;
            for (;;) {
                while (*q == ' ' || *q == '\t' || *q == '\r') q++;
                if (!*q || *q == '#') break;
                char *after;
                long i = strtol(q, &after, 10);
                if (after == q) break;
                q = after;
                while (*q && *q != ' ' && *q != '\t' && *q != '\r') q++; /* skip /t/n */
                if (n < 64) idx[n++] = i < 0 ? (long)m->nv + i : i - 1;
            }
            for (int k = 2; k < n; k++) push_triangle(m, (unsigned)idx[0], (unsigned)idx[k - 1], (unsigned)idx[k]);
        }
    }
}

int main(int argc, char **argv) {
    if (argc != 3) { fprintf(stderr, "usage: %s MESH.obj RAYS.txt\n", argv[0]); return 2; }
    size_t len;
    char *obj = read_all(argv[1], &len);
    Mesh m = {0};
    parse_obj(obj, &m);
    free(obj);

    RTCDevice device = rtcNewDevice(NULL);
    RTCScene scene = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), m.nv);
    memcpy(vb, m.v, m.nv * 3 * sizeof(float));
    unsigned *ib = rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), m.nt);
    memcpy(ib, m.t, m.nt * 3 * sizeof(unsigned));
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);

    char *rays = read_all(argv[2], &len);
    struct RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    size_t count = 0, hits = 0;
    double t_sum = 0;
    char *p = rays;
    while (*p) {
        char *end = strchr(p, '\n');
        if (end) *end = 0;
        char *q = p;
        double v[6];
        int ok = 1;
        for (int k = 0; k < 6; k++) {
            char *after;
            v[k] = strtod(q, &after);
            if (after == q) { ok = 0; break; }
            q = after;
        }
        if (ok) {
            struct RTCRayHit rh;
            rh.ray.org_x = (float)v[0]; rh.ray.org_y = (float)v[1]; rh.ray.org_z = (float)v[2];
            rh.ray.dir_x = (float)v[3]; rh.ray.dir_y = (float)v[4]; rh.ray.dir_z = (float)v[5];
            rh.ray.tnear = 0.0f; rh.ray.tfar = INFINITY; rh.ray.mask = 0xFFFFFFFF; rh.ray.flags = 0; rh.ray.time = 0.0f;
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID; rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(scene, &context, &rh);
            count++;
            if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) { hits++; t_sum += rh.ray.tfar; }
        }
        if (!end) break;
        p = end + 1;
    }
    printf("triangles=%zu rays=%zu hits=%zu t_sum=%.6g\n", m.nt, count, hits, t_sum);
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
    free(rays); free(m.v); free(m.t);
    return 0;
}
