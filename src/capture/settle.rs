//! A settled camera image at a pose the operator holds still.
//!
//! A streaming camera delivers frames that left the sensor some time before they arrive: a
//! frame grabbed right after the arm came to rest may show it still moving (a network stream
//! buffered behind a slow reader, a simulated stream paced on wall time while the world runs on
//! a virtual clock). While the arm is held still, consecutive frames differ only by sensor
//! noise, so the image is taken once two consecutive grabs agree block by block: the mean grey
//! level of every 32 × 32-pixel block within [`SETTLED_GREY`] levels (noise averages out over a
//! block; a board edge moving by a pixel shifts its block's mean by about two levels).

use std::future::Future;

use robocal_drivers::{Image, ImageSource};

/// Side of the blocks compared (px).
pub const BLOCK_PX: u32 = 32;
/// Largest change of a block's mean grey level between two settled frames.
pub const SETTLED_GREY: f64 = 1.5;
/// Grabs before the image counts as settled, at least (the first ones may be in flight).
pub const MIN_GRABS: usize = 3;
/// Grabs at most; then the last frame is used and the caller is told it never settled.
pub const MAX_GRABS: usize = 12;

/// A settled frame: the image and how many grabs it took.
#[derive(Debug, Clone)]
pub struct Settled {
    /// The last frame grabbed.
    pub image: Image,
    /// Frames grabbed.
    pub grabs: usize,
    /// Whether the last two frames agreed (false: [`MAX_GRABS`] reached while changing).
    pub settled: bool,
    /// The largest block change between the last two frames (grey levels).
    pub change_grey: f64,
}

/// Block means of `img` (row-major, ceil(w / B) × ceil(h / B) blocks).
fn block_means(img: &Image) -> Vec<f64> {
    let (w, h) = (img.width as usize, img.height as usize);
    let b = BLOCK_PX as usize;
    let (bw, bh) = (w.div_ceil(b), h.div_ceil(b));
    let mut sum = vec![0.0f64; bw * bh];
    let mut count = vec![0u32; bw * bh];
    for y in 0..h {
        let row = &img.data[y * w..(y + 1) * w];
        let by = y / b;
        for (x, &v) in row.iter().enumerate() {
            let k = by * bw + x / b;
            sum[k] += f64::from(v);
            count[k] += 1;
        }
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &c)| s / f64::from(c.max(1)))
        .collect()
}

/// The largest block-mean change between two frames (grey levels); infinite when the sizes
/// differ or a frame is malformed.
pub fn block_change(a: &Image, b: &Image) -> f64 {
    let n = |i: &Image| i.width as usize * i.height as usize;
    if a.width != b.width || a.height != b.height || a.data.len() != n(a) || b.data.len() != n(b) {
        return f64::INFINITY;
    }
    block_means(a)
        .iter()
        .zip(block_means(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Grabs from `camera` until two consecutive frames agree (at least [`MIN_GRABS`], at most
/// [`MAX_GRABS`] frames). Errors are the camera's.
pub async fn settled_grab(camera: &dyn ImageSource) -> robocal_drivers::DriverResult<Settled> {
    settle(|| camera.grab()).await
}

/// [`settled_grab`] over any frame source `grab`.
pub async fn settle<E, F, Fut>(mut grab: F) -> Result<Settled, E>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<Image, E>>,
{
    let mut last = grab().await?;
    let mut change = f64::INFINITY;
    for grabs in 2..=MAX_GRABS {
        let next = grab().await?;
        change = block_change(&last, &next);
        last = next;
        if grabs >= MIN_GRABS && change <= SETTLED_GREY {
            return Ok(Settled {
                image: last,
                grabs,
                settled: true,
                change_grey: change,
            });
        }
    }
    Ok(Settled {
        image: last,
        grabs: MAX_GRABS,
        settled: false,
        change_grey: change,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// A camera that shows a bright square moving right by `step` px per frame for `moving`
    /// frames, then resting; `noise` grey levels of per-pixel pseudo-noise on every frame.
    struct Scripted {
        frame: Mutex<u32>,
        moving: u32,
        step: u32,
        noise: u8,
    }

    impl Scripted {
        fn frame(&self) -> Result<Image, ()> {
            let mut f = self.frame.lock().unwrap();
            let k = *f;
            *f += 1;
            let x0 = 40 + self.step * k.min(self.moving);
            let (w, h) = (320u32, 240u32);
            let mut data = vec![60u8; (w * h) as usize];
            for y in 80..160u32 {
                for x in x0..x0 + 80 {
                    data[(y * w + x) as usize] = 200;
                }
            }
            let mut s = 0x9e37_79b9u32.wrapping_mul(k + 1);
            for v in &mut data {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                *v = v.saturating_add((s % (u32::from(self.noise) + 1)) as u8);
            }
            Ok(Image {
                width: w,
                height: h,
                data,
                t: f64::from(k),
            })
        }
    }

    fn run(cam: &Scripted) -> Settled {
        tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap()
            .block_on(settle(|| std::future::ready(cam.frame())))
            .unwrap()
    }

    #[test]
    fn waits_until_the_frames_stop_changing() {
        // Moving 2 px a frame for 5 frames: frames 0..=5 change, 6 equals 5 up to noise.
        let cam = Scripted {
            frame: Mutex::new(0),
            moving: 5,
            step: 2,
            noise: 6,
        };
        let s = run(&cam);
        assert!(s.settled, "{s:?}");
        assert_eq!(s.grabs, 7, "{s:?}");
        assert!(s.change_grey <= SETTLED_GREY, "{s:?}");
    }

    #[test]
    fn a_still_scene_takes_the_minimum_and_a_moving_one_says_so() {
        let still = Scripted {
            frame: Mutex::new(0),
            moving: 0,
            step: 2,
            noise: 6,
        };
        let s = run(&still);
        assert!(s.settled && s.grabs == MIN_GRABS, "{s:?}");
        let moving = Scripted {
            frame: Mutex::new(0),
            moving: 100,
            step: 1,
            noise: 0,
        };
        let m = run(&moving);
        assert!(!m.settled && m.grabs == MAX_GRABS, "{m:?}");
        assert!(m.change_grey > SETTLED_GREY, "{m:?}");
    }

    #[test]
    fn frames_of_other_sizes_never_agree() {
        let a = Image {
            width: 4,
            height: 4,
            data: vec![0; 16],
            t: 0.0,
        };
        let b = Image {
            width: 4,
            height: 2,
            data: vec![0; 8],
            t: 0.0,
        };
        assert!(block_change(&a, &b).is_infinite());
        assert_eq!(block_change(&a, &a), 0.0);
    }
}
