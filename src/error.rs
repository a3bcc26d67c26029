//! The crate-wide error: every module's typed error, for callers that handle them alike.

/// Any voxray error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Loading a mesh.
    #[error(transparent)]
    Mesh(#[from] crate::mesh::MeshError),
    /// Voxelizing.
    #[error(transparent)]
    Voxelize(#[from] crate::voxelize::VoxelizeError),
    /// Building an SVO.
    #[error(transparent)]
    Build(#[from] crate::svo::BuildError),
    /// Reading or writing an `.svo` file.
    #[error(transparent)]
    SvoFile(#[from] crate::svo::SvoFileError),
    /// Building or updating the scene.
    #[error(transparent)]
    Scene(#[from] crate::scene::SceneError),
    /// Posing an animated node hierarchy.
    #[error(transparent)]
    Pose(#[from] crate::scene::animation::PoseError),
    /// Reading a scene file (glTF, MagicaVoxel).
    #[error(transparent)]
    Import(#[from] crate::import::ImportError),
    /// Global illumination settings or inputs.
    #[error(transparent)]
    Gi(#[from] crate::gi::GiError),
    /// Casting rays at a scene.
    #[error(transparent)]
    Cast(#[from] crate::cast::CastError),
    /// The camera.
    #[error(transparent)]
    Camera(#[from] crate::scene::CameraError),
    /// The lights.
    #[error(transparent)]
    Lights(#[from] crate::scene::LightsError),
    /// Writing images or AOVs.
    #[error(transparent)]
    Output(#[from] crate::render::output::OutputError),
    /// The GPU path.
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    /// Reading an input file with its size limit.
    #[error(transparent)]
    Input(#[from] crate::input::InputError),
    /// Reading an input file (camera/lights JSON).
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// A large allocation the memory budget refused.
    #[error(transparent)]
    Memory(#[from] crate::memory::MemoryError),
    /// A car staged from other than its eight parts.
    #[error("a car has 8 parts ({}), got {got}", crate::model::car::PART_NAMES.join(", "))]
    CarParts {
        /// The parts given.
        got: usize,
    },
    /// A combination this build or backend does not run.
    #[error("{0}")]
    Unsupported(&'static str),
    /// The GPU backend was asked of a build without it.
    #[error("this build has no GPU support (the `gpu` feature)")]
    NoGpuSupport,
    /// The interactive window.
    #[cfg(feature = "viewer")]
    #[error(transparent)]
    Viewer(#[from] crate::viewer::ViewerError),
}
