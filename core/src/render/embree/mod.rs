//! Safe wrapper over Embree (3 or 4): the only module that calls into `embree-sys`.
//!
//! Embree's nouns become RAII types: [`Device`] and [`EmbreeScene`] release their handles on drop. A
//! committed Embree scene is immutable and Embree documents concurrent queries on it as thread-safe, which
//! is why the types are `Send + Sync` (stated once, below).

mod floor;

use std::mem::MaybeUninit;
use std::sync::OnceLock;
use std::time::Instant;

use embree_sys as sys;

use super::scene::RenderScene;
use super::tracer::{HitTracer, PACKET, RawHit, RayPacket};
use crate::{Error, Result};

/// Hits recorded per lane before the ray is retraced alone with a larger buffer.
const LANE_CAPACITY: usize = 64;

/// An Embree device.
pub struct Device {
    raw: sys::RTCDevice,
}

// SAFETY: an RTCDevice is internally synchronised; Embree allows use from any thread.
unsafe impl Send for Device {}
// SAFETY: as above; shared references only issue thread-safe calls.
unsafe impl Sync for Device {}

impl Device {
    /// Creates a device with Embree's default configuration.
    pub fn new() -> Result<Self> {
        // SAFETY: a null config string is documented as "default configuration".
        let raw = unsafe { sys::rtcNewDevice(std::ptr::null()) };
        if raw.is_null() {
            // SAFETY: rtcGetDeviceError accepts a null device and returns the thread's last error.
            let code = unsafe { sys::rtcGetDeviceError(std::ptr::null_mut()) };
            return Err(Error::External {
                library: "Embree",
                message: format!("could not create a device (error {})", error_name(code)),
            });
        }
        Ok(Device { raw })
    }

    fn check(&self, what: &str) -> Result<()> {
        // SAFETY: self.raw is a live device.
        let code = unsafe { sys::rtcGetDeviceError(self.raw) };
        if code == sys::RTC_ERROR_NONE {
            Ok(())
        } else {
            Err(Error::External {
                library: "Embree",
                message: format!("{what}: {}", error_name(code)),
            })
        }
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: self.raw was returned by rtcNewDevice and is released exactly once.
        unsafe { sys::rtcReleaseDevice(self.raw) }
    }
}

fn error_name(code: sys::RTCError) -> &'static str {
    match code {
        sys::RTC_ERROR_NONE => "no error",
        sys::RTC_ERROR_INVALID_ARGUMENT => "invalid argument",
        sys::RTC_ERROR_INVALID_OPERATION => "invalid operation",
        sys::RTC_ERROR_OUT_OF_MEMORY => "out of memory",
        sys::RTC_ERROR_UNSUPPORTED_CPU => "unsupported CPU",
        sys::RTC_ERROR_CANCELLED => "cancelled",
        _ => "unknown error",
    }
}

/// The process-wide device: creating one starts Embree's thread pool, which costs far more than a scene.
fn shared_device() -> Result<&'static Device> {
    static DEVICE: OnceLock<std::result::Result<Device, String>> = OnceLock::new();
    DEVICE
        .get_or_init(|| Device::new().map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|m| Error::External {
            library: "Embree",
            message: m.clone(),
        })
}

/// A committed Embree scene of triangle meshes (geometry id = mesh index in the [`RenderScene`]).
pub struct EmbreeScene {
    raw: sys::RTCScene,
    device: &'static Device,
    build_ms: f64,
    records_hits: bool,
}

// SAFETY: a committed scene is read-only; Embree documents rtcIntersect* on it as thread-safe.
unsafe impl Send for EmbreeScene {}
// SAFETY: as above.
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds the BVH. With `record_hits` every geometry gets the all-hits filter (for thickness DRRs);
    /// without it the scene answers plain closest-hit queries (the benchmark floor).
    pub fn new(scene: &RenderScene, record_hits: bool) -> Result<Self> {
        let device = shared_device()?;
        let start = Instant::now();
        // SAFETY: device is live; the returned scene is released in Drop (or below on error).
        let raw = unsafe { sys::rtcNewScene(device.raw) };
        let mut this = EmbreeScene {
            raw,
            device,
            build_ms: 0.0,
            records_hits: record_hits,
        };
        this.device.check("creating a scene")?;
        // Robust mode uses Embree's watertight triangle test: a ray through a shared edge is reported by at
        // least one of its triangles, so entries and exits pair up without retracing.
        // SAFETY: raw is a live, empty scene.
        unsafe { sys::rtcSetSceneFlags(raw, sys::RTC_SCENE_FLAG_ROBUST) };
        for (id, m) in scene.meshes.iter().enumerate() {
            this.attach_mesh(id as u32, &m.mesh)?;
        }
        // SAFETY: all geometries are committed and attached.
        unsafe { sys::rtcCommitScene(raw) };
        this.device.check("building the BVH")?;
        this.build_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(this)
    }

    fn attach_mesh(&self, id: u32, mesh: &crate::anatomy::TriMesh) -> Result<()> {
        let dev = self.device.raw;
        // SAFETY: dev is live; the geometry is released after attaching (the scene keeps a reference).
        unsafe {
            let geom = sys::rtcNewGeometry(dev, sys::RTC_GEOMETRY_TYPE_TRIANGLE);
            if geom.is_null() {
                self.device.check("creating a triangle geometry")?;
            }
            let nv = mesh.vertices.len();
            let nt = mesh.triangles.len();
            let vb = sys::rtcSetNewGeometryBuffer(
                geom,
                sys::RTC_BUFFER_TYPE_VERTEX,
                0,
                sys::RTC_FORMAT_FLOAT3,
                3 * std::mem::size_of::<f32>(),
                nv,
            ) as *mut f32;
            let ib = sys::rtcSetNewGeometryBuffer(
                geom,
                sys::RTC_BUFFER_TYPE_INDEX,
                0,
                sys::RTC_FORMAT_UINT3,
                3 * std::mem::size_of::<u32>(),
                nt,
            ) as *mut u32;
            if vb.is_null() || ib.is_null() {
                sys::rtcReleaseGeometry(geom);
                return Err(Error::External {
                    library: "Embree",
                    message: format!("could not allocate buffers for mesh '{}'", mesh.name),
                });
            }
            // Embree allocated nv·3 floats and nt·3 indices (plus its own padding).
            let verts = std::slice::from_raw_parts_mut(vb, nv * 3);
            for (dst, v) in verts.chunks_exact_mut(3).zip(&mesh.vertices) {
                dst.copy_from_slice(&[v.x as f32, v.y as f32, v.z as f32]);
            }
            let idx = std::slice::from_raw_parts_mut(ib, nt * 3);
            for (dst, t) in idx.chunks_exact_mut(3).zip(&mesh.triangles) {
                dst.copy_from_slice(t);
            }
            if self.records_hits {
                sys::spd_enable_hit_recording(geom);
            }
            sys::rtcCommitGeometry(geom);
            sys::rtcAttachGeometryByID(self.raw, geom, id);
            sys::rtcReleaseGeometry(geom);
        }
        self.device.check(&format!("adding mesh '{}'", mesh.name))
    }

    /// Closest-hit distances of a packet (`+inf` on a miss). For the benchmark floor; the scene must have
    /// been built without hit recording or every hit is rejected.
    pub fn first_hit(&self, packet: &RayPacket, t_out: &mut [f32; PACKET]) {
        let soa = Soa::from_packet(packet);
        // SAFETY: every array has PACKET lanes, n ≤ PACKET, and the scene is committed.
        unsafe {
            sys::spd_first_hit(
                self.raw,
                soa.width,
                soa.valid.as_ptr(),
                soa.ox.as_ptr(),
                soa.oy.as_ptr(),
                soa.oz.as_ptr(),
                soa.dx.as_ptr(),
                soa.dy.as_ptr(),
                soa.dz.as_ptr(),
                soa.tnear.as_ptr(),
                soa.tfar.as_ptr(),
                t_out.as_mut_ptr(),
            )
        }
    }

    /// Calls the shim's all-hits query on `n` lanes of `soa`.
    ///
    /// # Safety
    /// `hits` must hold `n × capacity` entries and `counts` `n` counters; the scene must have been built
    /// with hit recording.
    unsafe fn record_all_hits(
        &self,
        soa: &Soa,
        n: i32,
        hits: *mut sys::spd_hit,
        capacity: u32,
        counts: *mut u32,
    ) {
        // SAFETY: the arrays of `soa` have PACKET ≥ n lanes; the rest is the caller's contract.
        unsafe {
            sys::spd_all_hits(
                self.raw,
                n,
                soa.valid.as_ptr(),
                soa.ox.as_ptr(),
                soa.oy.as_ptr(),
                soa.oz.as_ptr(),
                soa.dx.as_ptr(),
                soa.dy.as_ptr(),
                soa.dz.as_ptr(),
                soa.tnear.as_ptr(),
                soa.tfar.as_ptr(),
                hits,
                capacity,
                counts,
            )
        }
    }

    /// Records all hits of a single ray with an exactly sized buffer (after a lane overflowed).
    fn all_hits_single(
        &self,
        packet: &RayPacket,
        lane: usize,
        expected: usize,
        out: &mut Vec<RawHit>,
    ) {
        let mut single = RayPacket::default();
        single.push(packet.origin[lane], packet.dir[lane]);
        let soa = Soa::from_packet(&single);
        let mut buf = vec![sys::spd_hit::default(); expected.max(1)];
        let mut count = [0u32; 1];
        // SAFETY: one lane, `buf` holds `expected` hits, `count` one counter.
        unsafe {
            self.record_all_hits(
                &soa,
                1,
                buf.as_mut_ptr(),
                buf.len() as u32,
                count.as_mut_ptr(),
            )
        }
        let n = (count[0] as usize).min(buf.len());
        out.extend(buf[..n].iter().map(to_raw));
    }
}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: self.raw was returned by rtcNewScene and is released exactly once; the device is static.
        unsafe { sys::rtcReleaseScene(self.raw) }
    }
}

fn to_raw(h: &sys::spd_hit) -> RawHit {
    RawHit {
        t: f64::from(h.t),
        geom: h.geom_id,
        prim: h.prim_id,
    }
}

/// Structure-of-arrays f32 copy of a packet, padded to the Embree packet width.
struct Soa {
    width: i32,
    valid: [i32; PACKET],
    ox: [f32; PACKET],
    oy: [f32; PACKET],
    oz: [f32; PACKET],
    dx: [f32; PACKET],
    dy: [f32; PACKET],
    dz: [f32; PACKET],
    tnear: [f32; PACKET],
    tfar: [f32; PACKET],
}

impl Soa {
    fn from_packet(p: &RayPacket) -> Self {
        let mut s = Soa {
            width: if p.len <= 1 {
                1
            } else if p.len <= 4 {
                4
            } else {
                8
            },
            valid: [0; PACKET],
            ox: [0.0; PACKET],
            oy: [0.0; PACKET],
            oz: [0.0; PACKET],
            dx: [0.0; PACKET],
            dy: [0.0; PACKET],
            dz: [1.0; PACKET],
            tnear: [0.0; PACKET],
            tfar: [f32::INFINITY; PACKET],
        };
        for i in 0..p.len {
            s.valid[i] = 1;
            s.ox[i] = p.origin[i].x as f32;
            s.oy[i] = p.origin[i].y as f32;
            s.oz[i] = p.origin[i].z as f32;
            s.dx[i] = p.dir[i].x as f32;
            s.dy[i] = p.dir[i].y as f32;
            s.dz[i] = p.dir[i].z as f32;
        }
        s
    }
}

/// Embree as a [`HitTracer`]: one BVH traversal per packet records every hit through the C filter.
pub struct EmbreeTracer {
    scene: EmbreeScene,
}

impl EmbreeTracer {
    pub fn new(scene: &RenderScene) -> Result<Self> {
        Ok(EmbreeTracer {
            scene: EmbreeScene::new(scene, true)?,
        })
    }

    /// Major version of the linked Embree.
    pub fn embree_major() -> u32 {
        sys::EMBREE_MAJOR
    }
}

impl HitTracer for EmbreeTracer {
    fn name(&self) -> &'static str {
        "embree"
    }

    fn build_ms(&self) -> f64 {
        self.scene.build_ms
    }

    fn trace_all(&self, packet: &RayPacket, hits: &mut [Vec<RawHit>; PACKET]) {
        let soa = Soa::from_packet(packet);
        // Left uninitialised: the shim writes hit k of a lane before its count passes k, and only the
        // first min(count, capacity) hits of each lane are read.
        let mut buf = [MaybeUninit::<sys::spd_hit>::uninit(); PACKET * LANE_CAPACITY];
        let mut counts = [0u32; PACKET];
        // SAFETY: arrays have PACKET lanes; `buf` holds PACKET × LANE_CAPACITY hits; the scene is committed
        // and was built with the recording filter.
        unsafe {
            self.scene.record_all_hits(
                &soa,
                soa.width,
                buf.as_mut_ptr().cast::<sys::spd_hit>(),
                LANE_CAPACITY as u32,
                counts.as_mut_ptr(),
            )
        }
        for lane in 0..packet.len {
            let out = &mut hits[lane];
            out.clear();
            let n = counts[lane] as usize;
            if n <= LANE_CAPACITY {
                let base = lane * LANE_CAPACITY;
                // SAFETY: the shim initialised the first n (≤ capacity) entries of this lane.
                out.extend(
                    buf[base..base + n]
                        .iter()
                        .map(|h| to_raw(unsafe { h.assume_init_ref() })),
                );
            } else {
                self.scene.all_hits_single(packet, lane, n, out);
            }
        }
    }
}
