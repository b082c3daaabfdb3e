//! Streams a DEM source the way conversion does, checking each run lies inside the grid it
//! declared (conversion indexes its scratch grid with it), for at most 2^20 samples.

const MAX_SAMPLES: u64 = 1 << 20;

pub fn stream(mut source: Box<dyn relief_core::dem::DemSource>) {
    let info = source.info().clone();
    let mut seen = 0u64;
    let _ = source.read(&mut |run| {
        assert!(
            run.row < info.height && run.x0 as u64 + run.values.len() as u64 <= info.width as u64,
            "run outside the {} x {} grid: row {}, x0 {}, {} values",
            info.width,
            info.height,
            run.row,
            run.x0,
            run.values.len()
        );
        seen += run.values.len() as u64;
        if seen > MAX_SAMPLES {
            return Err(relief_core::Error::InvalidArgument("fuzz: enough samples".into()));
        }
        Ok(())
    });
}
