//! What the criterion benches share: a small deterministic generator of test data.

/// Xorshift: uniform draws in [0, 1), the same on every machine.
pub struct Gen(pub u64);
impl Gen {
    pub fn u(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}
