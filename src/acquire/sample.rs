//! Averaging of tracker frames (with outlier rejection) and laser readings. Pure functions.
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// One visible marker sample: pose in the tracker frame (mm) and the tracker's fit RMS (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerSample {
    /// Marker pose in the tracker frame.
    pub pose: Isometry3<f64>,
    /// The tracker's fit RMS of this frame (mm).
    pub rms_mm: f64,
}

/// Average of several marker samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerAverage {
    /// Averaged pose (mean position, sign-aligned normalised mean quaternion).
    pub pose: Isometry3<f64>,
    /// Mean tracker fit RMS of the kept frames (mm).
    pub rms_mm: f64,
    /// RMS distance of the kept positions from their mean (mm).
    pub spread_mm: f64,
    /// Frames kept.
    pub kept: usize,
    /// Frames rejected as outliers.
    pub rejected: usize,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Averages marker samples, rejecting those farther from the component-wise median
/// position than `max(k · 1.4826 · MAD, floor_mm)` (MAD of the distances to the median).
/// Returns `None` for no samples.
pub fn average_markers(samples: &[MarkerSample], k: f64, floor_mm: f64) -> Option<MarkerAverage> {
    if samples.is_empty() {
        return None;
    }
    let comp = |i: usize| {
        let mut v: Vec<f64> = samples
            .iter()
            .map(|s| s.pose.translation.vector[i])
            .collect();
        median(&mut v)
    };
    let med = Point3::new(comp(0), comp(1), comp(2));
    let dist: Vec<f64> = samples
        .iter()
        .map(|s| (Point3::from(s.pose.translation.vector) - med).norm())
        .collect();
    let mut d = dist.clone();
    let mad = median(&mut d);
    let threshold = (k * 1.4826 * mad).max(floor_mm);
    let kept: Vec<&MarkerSample> = samples
        .iter()
        .zip(&dist)
        .filter(|(_, &d)| d <= threshold)
        .map(|(s, _)| s)
        .collect();
    // The median itself is within the threshold of at least half the samples.
    let n = kept.len().max(1) as f64;
    let mean: Vector3<f64> = kept
        .iter()
        .map(|s| s.pose.translation.vector)
        .sum::<Vector3<f64>>()
        / n;
    let q0 = kept[0].pose.rotation.into_inner();
    let mut qsum = Quaternion::new(0.0, 0.0, 0.0, 0.0);
    for s in &kept {
        let q = s.pose.rotation.into_inner();
        qsum += if q.dot(&q0) < 0.0 { -q } else { q };
    }
    let rot = UnitQuaternion::from_quaternion(qsum);
    let spread = (kept
        .iter()
        .map(|s| (s.pose.translation.vector - mean).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    let rms = kept.iter().map(|s| s.rms_mm).sum::<f64>() / n;
    Some(MarkerAverage {
        pose: Isometry3::from_parts(Translation3::from(mean), rot),
        rms_mm: rms,
        spread_mm: spread,
        kept: kept.len(),
        rejected: samples.len() - kept.len(),
    })
}

/// Mean of the valid laser readings (mm); `None` when fewer than half of `n_total` are valid.
pub fn average_range(valid: &[f64], n_total: usize) -> Option<f64> {
    if valid.is_empty() || 2 * valid.len() < n_total {
        return None;
    }
    Some(valid.iter().sum::<f64>() / valid.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn s(x: f64, y: f64, z: f64) -> MarkerSample {
        MarkerSample {
            pose: Isometry3::translation(x, y, z),
            rms_mm: 0.1,
        }
    }

    #[test]
    fn rejects_an_outlier_and_averages_the_rest() {
        let mut v: Vec<MarkerSample> = (0..10)
            .map(|i| s(100.0 + 0.01 * (i % 3) as f64, 50.0, -1500.0))
            .collect();
        v.push(s(105.0, 50.0, -1500.0));
        let a = average_markers(&v, 3.5, 0.05).unwrap();
        assert_eq!(a.rejected, 1);
        assert_eq!(a.kept, 10);
        assert!((a.pose.translation.vector.x - 100.009).abs() < 1e-9);
        assert!(a.spread_mm < 0.01);
        // Without the outlier rule the mean would be pulled 0.45 mm.
        let b = average_markers(&v, 1e9, 1e9).unwrap();
        assert!((b.pose.translation.vector.x - a.pose.translation.vector.x).abs() > 0.4);
    }

    #[test]
    fn quaternions_of_opposite_sign_average_correctly() {
        let r = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3);
        let neg = UnitQuaternion::new_unchecked(-r.into_inner());
        let v = [
            MarkerSample {
                pose: Isometry3::from_parts(Translation3::identity(), r),
                rms_mm: 0.1,
            },
            MarkerSample {
                pose: Isometry3::from_parts(Translation3::identity(), neg),
                rms_mm: 0.3,
            },
        ];
        let a = average_markers(&v, 3.0, 0.1).unwrap();
        assert!(a.pose.rotation.angle_to(&r) < 1e-12);
        assert!((a.rms_mm - 0.2).abs() < 1e-12);
    }

    #[test]
    fn range_needs_half_valid() {
        assert_eq!(average_range(&[10.0, 12.0], 4), Some(11.0));
        assert_eq!(average_range(&[10.0], 4), None);
        assert_eq!(average_range(&[], 0), None);
    }
}
