//! Render pipelines as the renderers build them: one shader module and layout, no multisampling,
//! both faces drawn (terrain is seen from below under cliffs, scanned meshes through their holes).

/// Depth buffer format: reversed z (1 at the near plane, 0 at infinity) in f32, for precision
/// from a metre to the horizon.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// What differs between the pipelines of a renderer.
pub(crate) struct PipelineSpec<'a> {
    pub label: &'a str,
    pub vs: &'a str,
    pub buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
    pub topology: wgpu::PrimitiveTopology,
    /// Which winding `@builtin(front_facing)` calls front.
    pub front_face: wgpu::FrontFace,
    pub depth_stencil: Option<wgpu::DepthStencilState>,
    pub fs: &'a str,
    pub targets: &'a [Option<wgpu::ColorTargetState>],
}

/// A reversed-z depth test on [`DEPTH_FORMAT`] (`compare` is `Greater` for "nearer").
pub(crate) fn depth_state(
    write: bool,
    compare: wgpu::CompareFunction,
    bias: wgpu::DepthBiasState,
) -> Option<wgpu::DepthStencilState> {
    Some(wgpu::DepthStencilState {
        format: DEPTH_FORMAT,
        depth_write_enabled: Some(write),
        depth_compare: Some(compare),
        stencil: wgpu::StencilState::default(),
        bias,
    })
}

/// Builds the pipeline `spec` describes from `module` with `layout`.
pub(crate) fn build_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    module: &wgpu::ShaderModule,
    spec: PipelineSpec<'_>,
) -> wgpu::RenderPipeline {
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(spec.label),
        layout: Some(layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some(spec.vs),
            compilation_options: Default::default(),
            buffers: spec.buffers,
        },
        primitive: wgpu::PrimitiveState {
            topology: spec.topology,
            strip_index_format: None,
            front_face: spec.front_face,
            cull_mode: None,
            unclipped_depth: false,
            polygon_mode: wgpu::PolygonMode::Fill,
            conservative: false,
        },
        depth_stencil: spec.depth_stencil,
        multisample: wgpu::MultisampleState::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some(spec.fs),
            compilation_options: Default::default(),
            targets: spec.targets,
        }),
        multiview_mask: None,
        cache: None,
    })
}

/// The bind group layout entry of a uniform buffer of `bytes` at binding 0, seen by both stages.
pub(crate) fn uniform_entry(bytes: u64) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding: 0,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(bytes),
        },
        count: None,
    }
}
