//! The GPU: instance, adapter, device and queue, headless or for a window surface.
//!
//! Without a GPU, Vulkan on the CPU (Mesa's lavapipe, Debian `mesa-vulkan-drivers`) is picked by
//! the same code path. The device asks for the adapter's own texture limits, since the heights
//! texture array is sized from them (`render::heights`).

use std::sync::{Arc, Mutex};

use crate::error::Result;

/// One device and queue, and what they are.
pub struct Gpu {
    pub instance: wgpu::Instance,
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    /// The first error wgpu reported outside an error scope; wgpu's default is to panic, relief
    /// turns it into an [`crate::AppError::Gpu`] at the next [`Gpu::check`].
    uncaptured: Arc<Mutex<Option<String>>>,
}

/// What to tell a user with no usable adapter.
const NO_ADAPTER_HINT: &str =
    "install a Vulkan driver (on Debian/Ubuntu without a GPU: apt-get install mesa-vulkan-drivers libvulkan1)";

impl Gpu {
    /// A device for offscreen rendering.
    pub fn headless() -> Result<Gpu> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Gpu::with_instance(instance, None)
    }

    /// A device on `instance` that can present to `surface` (when given).
    pub fn with_instance(instance: wgpu::Instance, surface: Option<&wgpu::Surface<'_>>) -> Result<Gpu> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| crate::app_error::gpu(format!("no graphics adapter ({e}); {NO_ADAPTER_HINT}")))?;
        let have = adapter.limits();
        let required_limits = wgpu::Limits {
            max_texture_dimension_2d: have.max_texture_dimension_2d,
            max_texture_array_layers: have.max_texture_array_layers,
            max_buffer_size: have.max_buffer_size,
            ..wgpu::Limits::default().using_resolution(have.clone())
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("relief"),
            required_features: wgpu::Features::empty(),
            required_limits,
            ..Default::default()
        }))
        .map_err(|e| crate::app_error::gpu(format!("cannot open the graphics device: {e}")))?;
        let uncaptured = Arc::new(Mutex::new(None));
        let sink = uncaptured.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let mut first = sink.lock().unwrap_or_else(|p| p.into_inner());
            if first.is_none() {
                *first = Some(e.to_string().lines().filter(|l| !l.trim().is_empty()).collect::<Vec<_>>().join(": "));
            }
        }));
        Ok(Gpu { instance, adapter, device, queue, uncaptured })
    }

    /// "name (backend, type)", for reports.
    pub fn describe(&self) -> String {
        let info = self.adapter.get_info();
        format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type)
    }

    /// Whether the adapter renders on the CPU (lavapipe, llvmpipe, WARP, …).
    pub fn is_software(&self) -> bool {
        self.adapter.get_info().device_type == wgpu::DeviceType::Cpu
    }

    /// Fails with the first GPU error reported since the device was made, if any.
    pub fn check(&self) -> Result<()> {
        match self.uncaptured.lock().unwrap_or_else(|p| p.into_inner()).take() {
            Some(e) => Err(crate::app_error::gpu(e)),
            None => Ok(()),
        }
    }

    /// Runs `f`, turning validation and out-of-memory errors it causes into [`crate::AppError::Gpu`]
    /// (for example a heights texture larger than the GPU's memory).
    pub fn scoped<T>(&self, what: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let value = f();
        let v = pollster::block_on(validation.pop());
        let o = pollster::block_on(oom.pop());
        if let Some(e) = v.or(o) {
            let msg = e.to_string().lines().filter(|l| !l.trim().is_empty()).collect::<Vec<_>>().join(": ");
            return Err(crate::app_error::gpu(format!("{what}: {msg}")));
        }
        value
    }

    /// Blocks until the queue is idle, then reports any GPU error.
    pub fn wait_idle(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::Wait { submission_index: None, timeout: None })
            .map_err(|e| crate::app_error::gpu(format!("waiting for the GPU: {e}")))?;
        self.check()
    }
}
