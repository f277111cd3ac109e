/* spinedrr's C shim over Embree 3 / 4: see spd_shim.h. */
#include "spd_shim.h"

#include <math.h>
#include <string.h>

/* The query context extended with the recording buffers; Embree hands the context pointer to the filter. */
typedef struct spd_context {
#if SPD_EMBREE_MAJOR >= 4
  struct RTCRayQueryContext base;
#else
  struct RTCIntersectContext base;
#endif
  spd_hit* hits;
  unsigned int capacity;
  unsigned int* counts;
  unsigned int lanes;
} spd_context;

int spd_embree_major(void) { return SPD_EMBREE_MAJOR; }

/* C versions of Embree's C++-only RTCRayN_* / RTCHitN_* accessors (the SoA layout of rtcore_ray.h, the same in
 * Embree 3 and 4): ray = org_xyz, tnear, dir_xyz, time, tfar, mask, id, flags; hit = Ng_xyz, u, v, primID, geomID. */
static inline float spd_ray_tfar(const struct RTCRayN* ray, unsigned int n, unsigned int i) {
  return ((const float*)ray)[8 * n + i];
}
static inline unsigned int spd_ray_id(const struct RTCRayN* ray, unsigned int n, unsigned int i) {
  return ((const unsigned int*)ray)[10 * n + i];
}
static inline unsigned int spd_hit_prim(const struct RTCHitN* hit, unsigned int n, unsigned int i) {
  return ((const unsigned int*)hit)[5 * n + i];
}
static inline unsigned int spd_hit_geom(const struct RTCHitN* hit, unsigned int n, unsigned int i) {
  return ((const unsigned int*)hit)[6 * n + i];
}

/* Records the candidate hit of every active lane and rejects it, so traversal continues to the far end.
 * The lane is identified by the ray id, not the position in the packet: Embree may call the filter with a
 * packet of another width than the query's. During filtering, tfar holds the candidate's distance. */
static void spd_record_filter(const struct RTCFilterFunctionNArguments* args) {
  spd_context* ctx = (spd_context*)args->context;
  const unsigned int n = args->N;
  for (unsigned int i = 0; i < n; i++) {
    if (args->valid[i] == 0) continue;
    const unsigned int lane = spd_ray_id(args->ray, n, i);
    if (lane >= ctx->lanes) continue; /* never expected; guards the buffers */
    const unsigned int k = ctx->counts[lane]++;
    if (k < ctx->capacity) {
      spd_hit* h = &ctx->hits[(size_t)lane * ctx->capacity + k];
      h->t = spd_ray_tfar(args->ray, n, i);
      h->geom_id = spd_hit_geom(args->hit, n, i);
      h->prim_id = spd_hit_prim(args->hit, n, i);
    }
    args->valid[i] = 0;
  }
}

void spd_enable_hit_recording(RTCGeometry geometry) {
  rtcSetGeometryIntersectFilterFunction(geometry, spd_record_filter);
}

#define SPD_FILL_PACKET(RH, N)                                   \
  for (int i = 0; i < (N); i++) {                                \
    RH.ray.org_x[i] = org_x[i];                                  \
    RH.ray.org_y[i] = org_y[i];                                  \
    RH.ray.org_z[i] = org_z[i];                                  \
    RH.ray.dir_x[i] = dir_x[i];                                  \
    RH.ray.dir_y[i] = dir_y[i];                                  \
    RH.ray.dir_z[i] = dir_z[i];                                  \
    RH.ray.tnear[i] = tnear[i];                                  \
    RH.ray.tfar[i] = tfar[i];                                    \
    RH.ray.time[i] = 0.0f;                                       \
    RH.ray.mask[i] = 0xFFFFFFFFu;                                \
    RH.ray.id[i] = (unsigned int)i;                              \
    RH.ray.flags[i] = 0;                                         \
    RH.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;                  \
    RH.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;               \
    valid_a[i] = valid ? (valid[i] ? -1 : 0) : -1;               \
  }

#if SPD_EMBREE_MAJOR >= 4
#define SPD_INIT_CONTEXT(CTX)                                    \
  rtcInitRayQueryContext(&(CTX).base);                           \
  struct RTCIntersectArguments args;                             \
  rtcInitIntersectArguments(&args);                              \
  args.context = &(CTX).base;                                    \
  args.flags = RTC_RAY_QUERY_FLAG_COHERENT;
#define SPD_INTERSECT1(SCENE, CTX, RH) rtcIntersect1((SCENE), (RH), &args)
#define SPD_INTERSECTN(N, VALID, SCENE, CTX, RH) rtcIntersect##N((VALID), (SCENE), (RH), &args)
#else
#define SPD_INIT_CONTEXT(CTX)                                    \
  rtcInitIntersectContext(&(CTX).base);                          \
  (CTX).base.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
#define SPD_INTERSECT1(SCENE, CTX, RH) rtcIntersect1((SCENE), &(CTX).base, (RH))
#define SPD_INTERSECTN(N, VALID, SCENE, CTX, RH) rtcIntersect##N((VALID), (SCENE), &(CTX).base, (RH))
#endif

static void spd_trace(RTCScene scene, int n, const int* valid,
                      const float* org_x, const float* org_y, const float* org_z,
                      const float* dir_x, const float* dir_y, const float* dir_z,
                      const float* tnear, const float* tfar, spd_context* ctx, float* t_hit) {
  SPD_INIT_CONTEXT(*ctx)
  if (n == 1) {
    struct RTCRayHit rh;
    int valid_a[1];
    rh.ray.org_x = org_x[0]; rh.ray.org_y = org_y[0]; rh.ray.org_z = org_z[0];
    rh.ray.dir_x = dir_x[0]; rh.ray.dir_y = dir_y[0]; rh.ray.dir_z = dir_z[0];
    rh.ray.tnear = tnear[0]; rh.ray.tfar = tfar[0]; rh.ray.time = 0.0f;
    rh.ray.mask = 0xFFFFFFFFu; rh.ray.id = 0; rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID; rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    valid_a[0] = valid ? valid[0] : 1;
    if (valid_a[0]) SPD_INTERSECT1(scene, *ctx, &rh);
    if (t_hit) t_hit[0] = (valid_a[0] && rh.hit.geomID != RTC_INVALID_GEOMETRY_ID) ? rh.ray.tfar : INFINITY;
  } else if (n == 4) {
    RTC_ALIGN(16) struct RTCRayHit4 rh;
    RTC_ALIGN(16) int valid_a[4];
    SPD_FILL_PACKET(rh, 4)
    SPD_INTERSECTN(4, valid_a, scene, *ctx, &rh);
    if (t_hit) for (int i = 0; i < 4; i++) t_hit[i] = (valid_a[i] && rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID) ? rh.ray.tfar[i] : INFINITY;
  } else if (n == 8) {
    RTC_ALIGN(32) struct RTCRayHit8 rh;
    RTC_ALIGN(32) int valid_a[8];
    SPD_FILL_PACKET(rh, 8)
    SPD_INTERSECTN(8, valid_a, scene, *ctx, &rh);
    if (t_hit) for (int i = 0; i < 8; i++) t_hit[i] = (valid_a[i] && rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID) ? rh.ray.tfar[i] : INFINITY;
  } else if (n == 16) {
    RTC_ALIGN(64) struct RTCRayHit16 rh;
    RTC_ALIGN(64) int valid_a[16];
    SPD_FILL_PACKET(rh, 16)
    SPD_INTERSECTN(16, valid_a, scene, *ctx, &rh);
    if (t_hit) for (int i = 0; i < 16; i++) t_hit[i] = (valid_a[i] && rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID) ? rh.ray.tfar[i] : INFINITY;
  }
}

void spd_all_hits(RTCScene scene, int n, const int* valid,
                  const float* org_x, const float* org_y, const float* org_z,
                  const float* dir_x, const float* dir_y, const float* dir_z,
                  const float* tnear, const float* tfar,
                  spd_hit* hits, unsigned int capacity, unsigned int* counts) {
  spd_context ctx;
  memset(&ctx, 0, sizeof ctx);
  ctx.hits = hits;
  ctx.capacity = capacity;
  ctx.counts = counts;
  ctx.lanes = (unsigned int)n;
  for (int i = 0; i < n; i++) counts[i] = 0;
  spd_trace(scene, n, valid, org_x, org_y, org_z, dir_x, dir_y, dir_z, tnear, tfar, &ctx, NULL);
}

void spd_first_hit(RTCScene scene, int n, const int* valid,
                   const float* org_x, const float* org_y, const float* org_z,
                   const float* dir_x, const float* dir_y, const float* dir_z,
                   const float* tnear, const float* tfar, float* t_hit) {
  spd_context ctx;
  memset(&ctx, 0, sizeof ctx);
  spd_trace(scene, n, valid, org_x, org_y, org_z, dir_x, dir_y, dir_z, tnear, tfar, &ctx, t_hit);
}
