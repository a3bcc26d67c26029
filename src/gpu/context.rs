//! The wgpu device: Vulkan (or Metal / DX12) only — never the GL backend, which silently
//! writes nothing to 3D storage textures — with the adapter's real limits and timestamp
//! queries where the adapter has them.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Why the GPU path cannot run.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter on the allowed backends.
    #[error("no GPU adapter found on Vulkan/Metal/DX12 ({0}); on Linux without a GPU install Mesa's software Vulkan driver (Debian: mesa-vulkan-drivers), or use the CPU backend")]
    NoAdapter(String),
    /// Device creation failed.
    #[error("GPU device: {0}")]
    Device(String),
    /// A buffer would exceed a device limit.
    #[error("{what} needs {size} bytes, more than this device allows ({limit} bytes){}", hint(what))]
    TooLarge {
        /// The buffer.
        what: &'static str,
        /// Bytes needed.
        size: u64,
        /// Device limit.
        limit: u64,
    },
    /// Reading results back failed.
    #[error("GPU readback: {0}")]
    Readback(String),
    /// Invalid GI settings or inputs.
    #[error(transparent)]
    Gi(#[from] crate::gi::GiError),
    /// The device rejected a command (a bug in voxray or the driver; the frame is not valid).
    #[error("GPU validation error: {0}")]
    Validation(String),
    /// The device ran out of memory.
    #[error("GPU out of memory: {0}; lower the image or GI volume resolution, or use the CPU backend")]
    OutOfMemory(String),
    /// The device was lost (driver reset, GPU removed); a new context is needed.
    #[error("GPU device lost: {0}")]
    Lost(String),
    /// The camera of the frame.
    #[error(transparent)]
    Camera(#[from] crate::scene::CameraError),
    /// Buffers the memory budget refused (before they were created).
    #[error(transparent)]
    Memory(#[from] crate::memory::MemoryError),
    /// Cars the GPU cannot pose as [`crate::scene::car::car_pose`] does (their instances are
    /// missing or not a car's), or a scene changed since the crowd was made for it.
    #[error("crowd posed on the GPU: {0}")]
    Crowd(String),
}

/// A wgpu error as the library's.
fn library_error(e: wgpu::Error) -> GpuError {
    match e {
        wgpu::Error::OutOfMemory { .. } => GpuError::OutOfMemory(e.to_string()),
        wgpu::Error::Validation { description, .. } => GpuError::Validation(description),
        wgpu::Error::Internal { description, .. } => GpuError::Device(description),
    }
}

/// What a user can do about a GI buffer too large for the device.
fn hint(what: &str) -> &'static str {
    if what.starts_with("the GI") {
        ": lower the GI volume's resolution (a dense volume: or use the sparse volume, which stores only the bricks voxels land in), or run GI on the CPU backend"
    } else {
        ""
    }
}

/// A device, its queue and what it can do.
pub struct GpuContext {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter name, backend, driver.
    pub info: wgpu::AdapterInfo,
    /// The limits requested (the adapter's own).
    pub limits: wgpu::Limits,
    /// Whether timestamp queries are available.
    pub timestamps: bool,
    /// The first error the device raised outside an error scope, and the loss of the device:
    /// kept for [`GpuContext::check`] instead of wgpu's default of panicking.
    faults: Arc<Mutex<Faults>>,
    /// Buffers created on this device so far ([`GpuContext::buffer`], [`GpuContext::buffer_init`]).
    buffers_created: AtomicU64,
    /// Bytes copied back to the host so far ([`crate::gpu::renderer::read`]).
    bytes_read_back: AtomicU64,
}

/// Errors the device reported outside [`GpuContext::scoped`].
#[derive(Default)]
struct Faults {
    uncaptured: Option<GpuError>,
    lost: Option<String>,
}

impl GpuContext {
    /// Restricts an instance descriptor to the backends we accept (never GL); `WGPU_BACKEND`
    /// may narrow them further.
    pub fn restrict_backends(desc: &mut wgpu::InstanceDescriptor) {
        let allowed = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
        desc.backends &= allowed;
        if desc.backends.is_empty() {
            desc.backends = allowed;
        }
    }

    /// A headless device.
    pub fn headless() -> Result<GpuContext, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        Self::restrict_backends(&mut desc);
        let instance = wgpu::Instance::new(desc);
        Ok(Self::with_surface(&instance, None)?.0)
    }

    /// A device that can present to `surface` (or any device, without one), and its adapter.
    pub fn with_surface(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<(GpuContext, wgpu::Adapter), GpuError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: surface,
            // We want the adapter's real limits (lavapipe allows 1024 invocations, not 256).
            apply_limit_buckets: false,
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let limits = adapter.limits();
        let timestamps = adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        // Timestamps where the adapter has them; a transparent-black sampler border for the GI
        // level texture (outside the volume is empty).
        let required_features =
            adapter.features() & (wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::ADDRESS_MODE_CLAMP_TO_BORDER);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("voxray"),
            required_features,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device(e.to_string()))?;
        let info = adapter.get_info();
        let faults = Arc::new(Mutex::new(Faults::default()));
        let sink = faults.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let mut f = sink.lock().unwrap_or_else(|p| p.into_inner());
            f.uncaptured.get_or_insert_with(|| library_error(e));
        }));
        let sink = faults.clone();
        device.set_device_lost_callback(move |reason, message| {
            let mut f = sink.lock().unwrap_or_else(|p| p.into_inner());
            f.lost.get_or_insert_with(|| format!("{reason:?}: {message}"));
        });
        let (buffers_created, bytes_read_back) = (AtomicU64::new(0), AtomicU64::new(0));
        Ok((GpuContext { device, queue, info, limits, timestamps, faults, buffers_created, bytes_read_back }, adapter))
    }

    /// The first error the device raised outside an error scope since the last check, or its
    /// loss (which stays: a lost device does nothing more).
    pub fn check(&self) -> Result<(), GpuError> {
        let mut f = self.faults.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(reason) = &f.lost {
            return Err(GpuError::Lost(reason.clone()));
        }
        match f.uncaptured.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Runs `work` with the device's validation and out-of-memory errors caught: the first
    /// one it raised is returned as the library's error (before `work`'s own result), and so
    /// is a lost device or an error raised earlier outside any scope.
    pub fn scoped<T>(&self, work: impl FnOnce() -> Result<T, GpuError>) -> Result<T, GpuError> {
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let out = work();
        // Scopes pop innermost first.
        let oom = pollster::block_on(memory.pop());
        let invalid = pollster::block_on(validation.pop());
        self.check()?;
        if let Some(e) = oom.or(invalid) {
            return Err(library_error(e));
        }
        out
    }

    /// A new buffer, counted in [`GpuContext::traffic`].
    pub fn buffer(&self, desc: &wgpu::BufferDescriptor<'_>) -> wgpu::Buffer {
        self.buffers_created.fetch_add(1, Ordering::Relaxed);
        self.device.create_buffer(desc)
    }

    /// A new buffer with contents, counted in [`GpuContext::traffic`].
    pub fn buffer_init(&self, desc: &wgpu::util::BufferInitDescriptor<'_>) -> wgpu::Buffer {
        use wgpu::util::DeviceExt;
        self.buffers_created.fetch_add(1, Ordering::Relaxed);
        self.device.create_buffer_init(desc)
    }

    /// Counts bytes copied back to the host.
    pub(crate) fn note_read_back(&self, bytes: u64) {
        self.bytes_read_back.fetch_add(bytes, Ordering::Relaxed);
    }

    /// Buffers created and bytes read back on this device so far: the difference over a
    /// frame is what the frame cost in allocations and host round trips.
    pub fn traffic(&self) -> (u64, u64) {
        (self.buffers_created.load(Ordering::Relaxed), self.bytes_read_back.load(Ordering::Relaxed))
    }

    /// One line naming the adapter.
    pub fn describe(&self) -> String {
        format!("{} ({:?}, {:?}, {})", self.info.name, self.info.backend, self.info.device_type, self.info.driver_info)
    }

    /// Checks buffers of `bytes` in all for `what` against the memory budget before they are
    /// created: on software and integrated GPUs device memory is the machine's memory, and a
    /// discrete GPU's own limit is caught after the fact as [`GpuError::OutOfMemory`].
    pub fn check_memory(&self, what: impl FnOnce() -> String, bytes: u64, advice: &str) -> Result<(), GpuError> {
        if bytes > crate::memory::budget() {
            crate::memory::check(&what(), bytes, advice)?;
        }
        Ok(())
    }

    /// Checks a storage binding's size against the device limit.
    pub fn check_binding(&self, what: &'static str, size: u64) -> Result<(), GpuError> {
        let limit = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
        if size > limit {
            return Err(GpuError::TooLarge { what, size, limit });
        }
        Ok(())
    }
    /// A compute pass with one bind group of buffers (`entries`, made by [`buffer_entry`]):
    /// its pipeline for `entry_point` of the WGSL `source`, and the group's layout. The
    /// small passes (scattering rows, posing a crowd, refitting a tree) are made this way.
    pub(crate) fn compute_pass(
        &self,
        label: &str,
        source: String,
        entry_point: &str,
        entries: &[wgpu::BindGroupLayoutEntry],
    ) -> (wgpu::ComputePipeline, wgpu::BindGroupLayout) {
        let device = &self.device;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry_point),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some(entry_point),
            compilation_options: Default::default(),
            cache: None,
        });
        (pipeline, layout)
    }
}

/// A compute stage's buffer binding: a uniform, read-only or read-write storage buffer
/// ([`BufferKind`]); `dynamic`: read at a dynamic offset, `Some(bytes)` at a time.
pub(crate) fn buffer_entry(binding: u32, kind: BufferKind, dynamic: Option<u64>) -> wgpu::BindGroupLayoutEntry {
    let ty = match kind {
        BufferKind::Uniform => wgpu::BufferBindingType::Uniform,
        BufferKind::Read => wgpu::BufferBindingType::Storage { read_only: true },
        BufferKind::Write => wgpu::BufferBindingType::Storage { read_only: false },
    };
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: dynamic.is_some(),
            min_binding_size: dynamic.and_then(wgpu::BufferSize::new),
        },
        count: None,
    }
}

/// What a [`buffer_entry`] binds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BufferKind {
    /// A uniform buffer.
    Uniform,
    /// A read-only storage buffer.
    Read,
    /// A read-write storage buffer.
    Write,
}

/// Tests' device: None (with a note) where there is none, except in CI, where a missing
/// adapter fails the test.
#[cfg(test)]
pub(crate) fn test_context() -> Option<std::sync::Arc<GpuContext>> {
    match GpuContext::headless() {
        Ok(c) => Some(std::sync::Arc::new(c)),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("CI needs a GPU adapter: {e}"),
        Err(e) => {
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}
