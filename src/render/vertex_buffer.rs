//! A growable GPU vertex buffer, shared by the terrain and mesh renderers.

/// A growable GPU vertex buffer.
pub(crate) struct VertexBuffer {
    pub(crate) buffer: wgpu::Buffer,
    capacity: u64,
    label: &'static str,
}

impl VertexBuffer {
    pub(crate) fn new(device: &wgpu::Device, label: &'static str, capacity: u64) -> VertexBuffer {
        let capacity = capacity.max(256);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: capacity,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        VertexBuffer { buffer, capacity, label }
    }

    pub(crate) fn write(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, bytes: &[u8]) {
        let len = bytes.len() as u64;
        if len > self.capacity {
            // Grow by half again so a slowly growing strip does not reallocate every update, but
            // not past the device's limit when `len` itself fits.
            let grown = (len + len / 2).next_multiple_of(256).min(device.limits().max_buffer_size);
            *self = VertexBuffer::new(device, self.label, grown.max(len));
        }
        if len > 0 {
            queue.write_buffer(&self.buffer, 0, bytes);
        }
    }
}
