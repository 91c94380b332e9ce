//! The run-time binding to NDI's OAPI (feature `optotrak`). Untested without the library.

use super::{Error, OptotrakConfig, DEFAULT_LIBRARIES};
use crate::error::{DriverError, DriverResult};
use crate::traits::{
    Clock, MarkerToTracker, MarkerTracker, SystemClock, ToolObservation, ToolStatus, TrackerFrame,
};
use async_trait::async_trait;
use libloading::Library;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::ffi::{c_char, c_int, c_uint, c_void, CString};
use std::sync::{Arc, Mutex};

/// `OPTOTRAK_QUATERN_RIGID_FLAG` (OAPI `ndopto.h`; value UNVERIFIED here).
const QUATERN_RIGID_FLAG: c_int = 0x0010;
/// A transform record flag meaning "rigid body not found" (OAPI `OPTOTRAK_UNDETERMINED_FLAG`;
/// value UNVERIFIED here).
const UNDETERMINED_FLAG: u32 = 0x0001;
/// Floats marking a missing value in OAPI data.
const BAD_FLOAT: f32 = -3.697314e28;

/// One quaternion rigid-body record as laid out by OAPI (`struct OptotrakRigidStruct` with
/// the `QuatTransformation` union member; UNVERIFIED layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
struct RigidRecord {
    rigid_id: i32,
    flags: i32,
    quaternion_error: f32,
    iterative_error: f32,
    q0: f32,
    qx: f32,
    qy: f32,
    qz: f32,
    x: f32,
    y: f32,
    z: f32,
}

type FnStr = unsafe extern "C" fn(*const c_char) -> c_int;
type FnUint = unsafe extern "C" fn(c_uint) -> c_int;
type FnVoid = unsafe extern "C" fn() -> c_int;
type FnAddRigid = unsafe extern "C" fn(c_int, c_int, *const c_char, c_int) -> c_int;
type FnSetup =
    unsafe extern "C" fn(c_int, f32, f32, c_int, c_int, c_int, f32, f32, f32, f32, c_int) -> c_int;
type FnTransforms =
    unsafe extern "C" fn(*mut c_uint, *mut c_uint, *mut c_uint, *mut c_void) -> c_int;
type FnErrStr = unsafe extern "C" fn(*mut c_char, c_int) -> c_int;

/// An Optotrak Certus driven through the OAPI library.
pub struct Optotrak {
    lib: Mutex<Library>,
    tools: Vec<String>,
    clock: Arc<dyn Clock>,
}

impl std::fmt::Debug for Optotrak {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Optotrak")
            .field("tools", &self.tools)
            .finish()
    }
}

fn cstr(s: &str) -> CString {
    CString::new(s.replace('\0', "")).unwrap_or_default()
}

fn sym<T: Copy>(lib: &Library, name: &str) -> Result<T, Error> {
    let mut z = name.as_bytes().to_vec();
    z.push(0);
    // SAFETY: the symbol type is the OAPI prototype named in the module docs.
    unsafe { lib.get::<T>(z.as_slice()) }
        .map(|s| *s)
        .map_err(|_| Error::MissingSymbol(name.into()))
}

fn last_error(lib: &Library) -> String {
    let Ok(f) = sym::<FnErrStr>(lib, "OptotrakGetErrorString") else {
        return "no error text".into();
    };
    let mut buf = vec![0 as c_char; 1024];
    // SAFETY: the buffer is writable for its full length, which is passed.
    unsafe { f(buf.as_mut_ptr(), buf.len() as c_int) };
    let bytes: Vec<u8> = buf
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c as u8)
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

fn check(lib: &Library, call: &str, rc: c_int) -> Result<(), Error> {
    if rc == 0 {
        Ok(())
    } else {
        Err(Error::Call {
            call: call.into(),
            message: last_error(lib),
        })
    }
}

impl Optotrak {
    /// Load the library and start collection (blocking; seconds on real hardware).
    pub fn open(config: &OptotrakConfig) -> Result<Self, Error> {
        let tried: Vec<String> = match &config.library {
            Some(p) => vec![p.clone()],
            None => DEFAULT_LIBRARIES.iter().map(|s| s.to_string()).collect(),
        };
        let mut last = String::new();
        let mut lib = None;
        for name in &tried {
            // SAFETY: loading runs the library's initialisers; OAPI is a plain C library.
            match unsafe { Library::new(name) } {
                Ok(l) => {
                    lib = Some(l);
                    break;
                }
                Err(e) => last = e.to_string(),
            }
        }
        let lib = lib.ok_or(Error::LibraryMissing {
            tried,
            message: last,
        })?;
        let marker_total: u32 = config.rigid_bodies.iter().map(|(_, n)| n).sum();
        // SAFETY (all calls below): OAPI prototypes as documented; strings are NUL-terminated
        // and outlive the calls.
        unsafe {
            let sys = cstr(&config.system_file);
            check(
                &lib,
                "TransputerLoadSystem",
                sym::<FnStr>(&lib, "TransputerLoadSystem")?(sys.as_ptr()),
            )?;
            check(
                &lib,
                "TransputerInitializeSystem",
                sym::<FnUint>(&lib, "TransputerInitializeSystem")?(0),
            )?;
            let cam = cstr(&config.camera_file);
            check(
                &lib,
                "OptotrakLoadCameraParameters",
                sym::<FnStr>(&lib, "OptotrakLoadCameraParameters")?(cam.as_ptr()),
            )?;
            let mut start = 1;
            for (i, (file, n)) in config.rigid_bodies.iter().enumerate() {
                let f = cstr(file);
                check(
                    &lib,
                    "RigidBodyAddFromFile",
                    sym::<FnAddRigid>(&lib, "RigidBodyAddFromFile")?(
                        i as c_int,
                        start,
                        f.as_ptr(),
                        QUATERN_RIGID_FLAG,
                    ),
                )?;
                start += *n as c_int;
            }
            check(
                &lib,
                "OptotrakSetupCollection",
                sym::<FnSetup>(&lib, "OptotrakSetupCollection")?(
                    marker_total as c_int,
                    config.frame_hz,
                    2500.0,
                    30,
                    160,
                    0,
                    0.4,
                    7.5,
                    1.0,
                    0.0,
                    0,
                ),
            )?;
            check(
                &lib,
                "OptotrakActivateMarkers",
                sym::<FnVoid>(&lib, "OptotrakActivateMarkers")?(),
            )?;
        }
        Ok(Self {
            lib: Mutex::new(lib),
            tools: config.rigid_bodies.iter().map(|(f, _)| f.clone()).collect(),
            clock: Arc::new(SystemClock::default()),
        })
    }

    fn latest(&self) -> Result<TrackerFrame, Error> {
        let lib = self.lib.lock().unwrap_or_else(|e| e.into_inner());
        let mut frame: c_uint = 0;
        let mut elements: c_uint = 0;
        let mut flags: c_uint = 0;
        let mut recs = vec![RigidRecord::default(); self.tools.len().max(1)];
        // SAFETY: the buffer holds one record per rigid body added in `open`.
        let rc = unsafe {
            sym::<FnTransforms>(&lib, "DataGetLatestTransforms")?(
                &mut frame,
                &mut elements,
                &mut flags,
                recs.as_mut_ptr().cast(),
            )
        };
        check(&lib, "DataGetLatestTransforms", rc)?;
        let tools = recs
            .iter()
            .take((elements as usize).min(self.tools.len()))
            .zip(&self.tools)
            .map(|(r, name)| {
                let bad = (r.flags as u32) & UNDETERMINED_FLAG != 0
                    || [r.q0, r.qx, r.qy, r.qz, r.x, r.y, r.z]
                        .iter()
                        .any(|v| !v.is_finite() || *v <= BAD_FLOAT);
                let status = if bad {
                    ToolStatus::Missing
                } else {
                    ToolStatus::Visible {
                        pose: MarkerToTracker(Isometry3::from_parts(
                            Translation3::new(f64::from(r.x), f64::from(r.y), f64::from(r.z)),
                            UnitQuaternion::from_quaternion(Quaternion::new(
                                f64::from(r.q0),
                                f64::from(r.qx),
                                f64::from(r.qy),
                                f64::from(r.qz),
                            )),
                        )),
                        rms_mm: f64::from(r.quaternion_error),
                    }
                };
                ToolObservation {
                    tool: name.clone(),
                    status,
                }
            })
            .collect();
        Ok(TrackerFrame {
            frame_number: u64::from(frame),
            t: self.clock.now(),
            tools,
        })
    }
}

impl Drop for Optotrak {
    fn drop(&mut self) {
        let lib = self.lib.lock().unwrap_or_else(|e| e.into_inner());
        // SAFETY: OAPI shutdown calls take no arguments.
        unsafe {
            if let Ok(f) = sym::<FnVoid>(&lib, "OptotrakDeActivateMarkers") {
                f();
            }
            if let Ok(f) = sym::<FnVoid>(&lib, "TransputerShutdownSystem") {
                f();
            }
        }
    }
}

#[async_trait]
impl MarkerTracker for Optotrak {
    async fn frame(&self) -> DriverResult<TrackerFrame> {
        self.latest()
            .map_err(|e| DriverError::from_device("optotrak", e))
    }
}
