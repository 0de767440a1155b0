//! View directions: a Fibonacci sphere, evenly spread.

use glam::DVec3;

/// `n` unit directions evenly spread over the sphere; y is up.
pub fn fibonacci_sphere(n: usize) -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2 * i + 1) as f64 / n as f64;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), y, r * phi.sin())
        })
        .collect()
}
