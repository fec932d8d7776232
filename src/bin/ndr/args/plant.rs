//! The simulated drive's limits on the command line.

/// The simulated drive's limits, for `demo` and `remote`.
#[derive(clap::Args, Clone, Debug)]
pub struct PlantArgs {
    /// The largest command the simulated drive takes on each axis, either
    /// way: larger ones are saturated to ±this value, as a real drive
    /// saturates.
    #[arg(long, value_name = "U", default_value_t = 1000.0)]
    pub max_command: f64,
}

impl PlantArgs {
    /// The saturation, checked.
    pub fn max_command(&self) -> Result<f64, String> {
        if self.max_command.is_finite() && self.max_command > 0.0 {
            Ok(self.max_command)
        } else {
            Err(format!(
                "--max-command must be a positive number, got {}",
                self.max_command
            ))
        }
    }
}
