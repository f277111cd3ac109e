/* spinedrr's C shim over Embree 3 / 4.
 *
 * It exists for what bindgen cannot bind (Embree's static inline helpers such as rtcInitIntersectContext)
 * and to hide the 3-vs-4 differences of the query calls. It also hosts the intersection filter that
 * records every hit of a ray and rejects it, so one BVH traversal gathers all hits ("next hit" technique);
 * keeping that callback in C keeps the hot path free of FFI trampolines.
 */
#ifndef SPD_SHIM_H
#define SPD_SHIM_H

#if SPD_EMBREE_MAJOR >= 4
#include <embree4/rtcore.h>
#else
#include <embree3/rtcore.h>
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* One recorded hit: distance along the ray (in the units of the ray direction), geometry and primitive. */
typedef struct spd_hit {
  float t;
  unsigned int geom_id;
  unsigned int prim_id;
} spd_hit;

/* Major version of the Embree the shim was compiled against (3 or 4). */
int spd_embree_major(void);

/* Installs the recording intersection filter on a triangle geometry (before rtcCommitGeometry). */
void spd_enable_hit_recording(RTCGeometry geometry);

/* Traces a packet of `n` rays (n = 1, 4, 8 or 16; lanes with valid[i] == 0 are inactive) through `scene`,
 * recording every hit of lane i into hits[i * capacity ...] and its count into counts[i]. A count larger
 * than `capacity` means hits were dropped (the caller retraces that lane with a larger buffer). Ray data is
 * structure-of-arrays: org_x[i], …, dir_z[i]; tnear/tfar per lane. */
void spd_all_hits(RTCScene scene, int n, const int* valid,
                  const float* org_x, const float* org_y, const float* org_z,
                  const float* dir_x, const float* dir_y, const float* dir_z,
                  const float* tnear, const float* tfar,
                  spd_hit* hits, unsigned int capacity, unsigned int* counts);

/* Closest hit of a packet of `n` rays (n = 1, 4, 8 or 16) in a scene without recording filters: the floor
 * against which the all-hits query is benchmarked. Writes t (or +inf on a miss) per lane. */
void spd_first_hit(RTCScene scene, int n, const int* valid,
                   const float* org_x, const float* org_y, const float* org_z,
                   const float* dir_x, const float* dir_y, const float* dir_z,
                   const float* tnear, const float* tfar, float* t_hit);

#ifdef __cplusplus
}
#endif

#endif
