//! The messages the library logs (a cut or a carve refused, a fit that did not converge),
//! printed on stderr: warnings and errors by default, more with `SOFT_TISSUE_LOG=info` or
//! `debug`, none with `off`. Without a logger the `log` facade drops them, and a user of
//! `simulate` never saw why a carve did not land.

use log::{Level, LevelFilter, Log, Metadata, Record};

/// The variable that sets the level.
pub(crate) const VARIABLE: &str = "SOFT_TISSUE_LOG";

struct Stderr;

impl Log for Stderr {
    fn enabled(&self, metadata: &Metadata) -> bool {
        metadata.level() <= log::max_level()
    }

    fn log(&self, record: &Record) {
        if self.enabled(record.metadata()) {
            eprintln!("{}", line(record.level(), record.args()));
        }
    }

    fn flush(&self) {}
}

/// One message as printed.
fn line(level: Level, message: &std::fmt::Arguments) -> String {
    format!("{}: {message}", level.as_str().to_lowercase())
}

/// The level `value` names (`off`, `error`, `warn`, `info`, `debug`, `trace`; any case), or
/// `None`.
fn parse(value: &str) -> Option<LevelFilter> {
    value.trim().parse().ok()
}

/// Installs the logger at the level `SOFT_TISSUE_LOG` names (warnings where it is unset; an
/// unknown value is said so and taken as unset).
pub(crate) fn install() {
    let level = match std::env::var(VARIABLE) {
        Ok(v) => parse(&v).unwrap_or_else(|| {
            eprintln!(
                "warning: {VARIABLE}={v:?} is no level (off, error, warn, info, debug, trace): warnings shown"
            );
            LevelFilter::Warn
        }),
        Err(_) => LevelFilter::Warn,
    };
    if log::set_logger(&Stderr).is_ok() {
        log::set_max_level(level);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_parse_by_name_and_lines_name_their_level() {
        assert_eq!(parse("warn"), Some(LevelFilter::Warn));
        assert_eq!(parse(" Info "), Some(LevelFilter::Info));
        assert_eq!(parse("off"), Some(LevelFilter::Off));
        assert_eq!(parse("loud"), None);
        assert_eq!(
            line(Level::Warn, &format_args!("body `Liver`: not cut")),
            "warn: body `Liver`: not cut"
        );
    }
}
