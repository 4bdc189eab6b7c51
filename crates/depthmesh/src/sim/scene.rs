//! Simulator scenes: a TOML file of objects placed in a y-up world, plus the
//! parameters of the helical sensor path around them.
//!
//! The schema, every key shown (only `shape` and the shape's own dimensions
//! are required):
//!
//! ```toml
//! name = "table"          # defaults to the file name without extension
//! [helix]                 # optional; parameters of the thesis's helical sensor path
//! height = [0.75, 1.5]    # sensor height at start and end (default [0.75, 1.5])
//! look_at = [[0.0, 0.4, 0.0], [0.0, 0.6, 0.0]]   # target at start and end (default these)
//! margin = 4.0            # added to the non-floor objects' x and z extents to get the helix diameters (default 4.0 = 3 m + 1 m)
//! turns = 2.0             # default 2
//! [[object]]
//! name = "floor"          # defaults to "object N"
//! shape = "box"           # box | cylinder | sphere | plane | mesh
//! size = [10.0, 0.1, 10.0]     # box: [x, y, z] full extents; plane: [x, z]
//! # radius = 0.03              # cylinder, sphere
//! # height = 0.12              # cylinder (along y)
//! # segments = 64              # cylinder (default 64), sphere (default 32)
//! translation = [0.0, 0.05, 0.0]
//! rotation = [0.0, 0.0, 0.0]   # degrees about x, then y, then z (optional)
//! scale = 1.0                  # number or [sx, sy, sz] (optional)
//! floor = true                 # excluded from the helix bounds (optional)
//! returns = false              # a black or shiny surface: hides what is behind it but gives no depth (default true)
//! appear_at = 26               # optional: present from this iteration on (iterations are 1-based)
//! remove_at = 30               # optional: absent from this iteration on
//! dynamic = { appear_at = 26 } # optional: appear_at/remove_at that apply only in dynamic runs
//! motion = { by = [1.5, 0.0, 0.0], from = 40, until = 60 }   # optional: moves `by` metres evenly over iterations from..until, then stays
//! # path = "${bunny}"          # mesh shape only: file path relative to the scene file, or a ${variable} given by the caller
//! ```
//!
//! Objects are scaled, then rotated, then translated. Primitives are centred
//! at the origin before that; a mesh keeps its file's coordinates. A mesh
//! path that begins with `${var}` is taken as the caller gave it (relative to
//! the working directory); any other relative path is relative to the scene
//! file, so scenes can ship beside their meshes. `scenes/example.toml` is a
//! commented scene using every key.

use super::shapes;
use crate::error::{Error, Result};
use crate::mesh::{io::read_mesh, Aabb, Mesh};
use glam::{Mat3, Vec2, Vec3};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// What the caller supplies beyond the scene file.
#[derive(Clone, Debug, Default)]
pub struct SceneOptions {
    /// Values of `${name}` in mesh paths, usually from `--name PATH` flags.
    pub variables: BTreeMap<String, PathBuf>,
    /// Whether objects' `dynamic` appear/remove iterations apply.
    pub dynamic: bool,
}

/// The helical sensor path of the MABDI thesis: two turns around the objects,
/// rising while looking at a slowly rising point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HelixParams {
    /// Sensor height (world y, metres) at the start and the end.
    pub height: [f32; 2],
    /// World point looked at, at the start and the end.
    pub look_at: [Vec3; 2],
    /// Metres added to the objects' x and z extents to get the helix diameters.
    pub margin: f32,
    /// Number of turns around the objects.
    pub turns: f32,
}

impl Default for HelixParams {
    /// The table run of the thesis: 0.75 → 1.5 m, looking at (0, 0.4, 0) → (0, 0.6, 0),
    /// diameters = extents + 3 m + 1 m, two turns.
    fn default() -> Self {
        HelixParams {
            height: [0.75, 1.5],
            look_at: [Vec3::new(0.0, 0.4, 0.0), Vec3::new(0.0, 0.6, 0.0)],
            margin: 4.0,
            turns: 2.0,
        }
    }
}

/// One object of a scene, already placed in the world.
#[derive(Clone, Debug)]
pub struct SceneObject {
    /// Name from the scene file (or "object N").
    pub name: String,
    /// The surface in world coordinates, with per-vertex normals.
    pub mesh: Mesh,
    /// Floors are left out of the bounds the helix goes around.
    pub floor: bool,
    /// Whether the sensor measures the surface; `false` makes a black or
    /// shiny object that hides what is behind it but returns no depth.
    pub returns: bool,
    /// First iteration (1-based) at which the object exists, if not from the start.
    pub appear_at: Option<u32>,
    /// First iteration at which the object no longer exists, if ever.
    pub remove_at: Option<u32>,
    /// How the object moves during the run, if it does.
    pub motion: Option<Motion>,
}

/// A straight move of an object: a person walking through the view, a
/// chair pushed aside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    /// The whole displacement, metres in world axes.
    pub by: Vec3,
    /// The last iteration at the object's placement; the move starts after it.
    pub from: u32,
    /// The iteration by which the move is made; the object stays there after.
    pub until: u32,
}

impl Motion {
    /// How far the object has moved from its placement at `iteration`.
    pub fn offset_at(&self, iteration: u32) -> Vec3 {
        let done = iteration.clamp(self.from, self.until) - self.from;
        self.by * (done as f32 / (self.until - self.from) as f32)
    }
}

impl SceneObject {
    /// Whether the object exists at `iteration` (1-based).
    pub fn present_at(&self, iteration: u32) -> bool {
        self.appear_at.is_none_or(|a| iteration >= a)
            && self.remove_at.is_none_or(|r| iteration < r)
    }

    /// Where the object is at `iteration`: its offset from its placement
    /// when it exists then, `None` when it does not. Two iterations with the
    /// same state image the same world.
    pub fn state_at(&self, iteration: u32) -> Option<Vec3> {
        self.present_at(iteration)
            .then(|| self.motion.map_or(Vec3::ZERO, |m| m.offset_at(iteration)))
    }
}

/// A simulated world: objects that may appear or vanish over the iterations of a run.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Scene name, for reports.
    pub name: String,
    /// Objects in file order; their indices are the object ids of [`Scene::world_mesh`].
    pub objects: Vec<SceneObject>,
    /// Parameters of the helical sensor path.
    pub helix: HelixParams,
}

impl Scene {
    /// Reads and builds the scene file at `path`.
    pub fn load(path: &Path, options: &SceneOptions) -> Result<Scene> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Scene::parse(&text, path, options)
    }

    /// Builds a scene from TOML `text`; `source` is the file it came from, for
    /// relative mesh paths and error messages.
    pub fn parse(text: &str, source: &Path, options: &SceneOptions) -> Result<Scene> {
        let fail = |message: String| Error::format(source, message);
        let file: SceneFile =
            toml::from_str(text).map_err(|e| fail(describe_toml_error(text, &e)))?;
        let helix = file
            .helix
            .params()
            .map_err(|m| fail(format!("[helix]: {m}")))?;
        if file.object.is_empty() {
            return Err(fail("the scene has no [[object]]".into()));
        }
        let objects = file
            .object
            .iter()
            .enumerate()
            .map(|(i, spanned)| {
                let object = spanned.get_ref();
                let name = object
                    .name
                    .clone()
                    .unwrap_or_else(|| format!("object {}", i + 1));
                object.build(&name, source, options).map_err(|m| {
                    let line = line_of(text, spanned.span().start);
                    let label = object_label(i, object.name.as_deref());
                    fail(format!("{label} (line {line}): {m}"))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let name = file.name.unwrap_or_else(|| {
            source
                .file_stem()
                .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned())
        });
        Ok(Scene {
            name,
            objects,
            helix,
        })
    }

    /// The world at `iteration` (1-based): the merged mesh of the objects
    /// present then, where they are then, and the index in
    /// [`Scene::objects`] of each triangle's object.
    pub fn world_mesh(&self, iteration: u32) -> (Mesh, Vec<u32>) {
        self.merge(|o| o.state_at(iteration))
    }

    /// The state of every object at `iteration` ([`SceneObject::state_at`]).
    pub fn state_at(&self, iteration: u32) -> Vec<Option<Vec3>> {
        self.objects.iter().map(|o| o.state_at(iteration)).collect()
    }

    /// Every object merged, whenever it exists, where it was placed.
    pub fn full_mesh(&self) -> Mesh {
        self.merge(|_| Some(Vec3::ZERO)).0
    }

    /// Bounds of the non-floor objects over the whole run (all objects if every one is a floor):
    /// what the sensor path goes around.
    pub fn object_bounds(&self) -> Aabb {
        let any_object = self.objects.iter().any(|o| !o.floor);
        let mut bounds = Aabb::EMPTY;
        for o in self.objects.iter().filter(|o| !(any_object && o.floor)) {
            let b = o.mesh.bounds();
            bounds.include(b.min);
            bounds.include(b.max);
        }
        bounds
    }

    /// The objects `offset` places (moved by the offset), merged.
    fn merge(&self, offset: impl Fn(&SceneObject) -> Option<Vec3>) -> (Mesh, Vec<u32>) {
        let mut mesh = Mesh::default();
        let mut ids = Vec::new();
        for (i, object) in self.objects.iter().enumerate() {
            let Some(offset) = offset(object) else {
                continue;
            };
            let start = mesh.positions.len();
            mesh.append(&object.mesh);
            if offset != Vec3::ZERO {
                mesh.positions[start..]
                    .iter_mut()
                    .for_each(|p| *p += offset);
            }
            ids.resize(mesh.triangle_count(), i as u32);
        }
        (mesh, ids)
    }
}

/// How to supply a missing `${name}`: the CLI has one `--name PATH` flag per variable.
fn how_to_pass(variable: &str) -> String {
    match variable {
        "bunny" => "pass the bunny mesh with --bunny PATH (e.g. the Stanford bunny PLY)".into(),
        _ => format!("pass --{variable} PATH"),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: Option<String>,
    #[serde(default)]
    helix: HelixFile,
    #[serde(default)]
    object: Vec<Spanned<ObjectFile>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct HelixFile {
    height: [f32; 2],
    look_at: [[f32; 3]; 2],
    margin: f32,
    turns: f32,
}

impl Default for HelixFile {
    fn default() -> Self {
        let d = HelixParams::default();
        HelixFile {
            height: d.height,
            look_at: d.look_at.map(|v| v.to_array()),
            margin: d.margin,
            turns: d.turns,
        }
    }
}

impl HelixFile {
    fn params(&self) -> Result<HelixParams, String> {
        check_finite("height", &self.height)?;
        check_finite("look_at", self.look_at.as_flattened())?;
        check_finite("turns", &[self.turns])?;
        if !(self.margin >= 0.0 && self.margin.is_finite()) {
            return Err(format!(
                "`margin` must be finite and not negative, got {}",
                self.margin
            ));
        }
        Ok(HelixParams {
            height: self.height,
            look_at: self.look_at.map(Vec3::from),
            margin: self.margin,
            turns: self.turns,
        })
    }
}

#[derive(Clone, Copy, Deserialize, PartialEq)]
#[serde(rename_all = "lowercase")]
enum Shape {
    #[serde(rename = "box")]
    Cuboid,
    Cylinder,
    Sphere,
    Plane,
    Mesh,
}

impl Shape {
    fn name(self) -> &'static str {
        match self {
            Shape::Cuboid => "box",
            Shape::Cylinder => "cylinder",
            Shape::Sphere => "sphere",
            Shape::Plane => "plane",
            Shape::Mesh => "mesh",
        }
    }

    /// The shape-specific keys it reads; any other one given is a mistake worth reporting.
    fn keys(self) -> &'static [&'static str] {
        match self {
            Shape::Cuboid | Shape::Plane => &["size"],
            Shape::Cylinder => &["radius", "height", "segments"],
            Shape::Sphere => &["radius", "segments"],
            Shape::Mesh => &["path"],
        }
    }
}

#[derive(Deserialize)]
#[serde(untagged, expecting = "a number or an array of three numbers")]
enum Scale {
    Uniform(f32),
    Axes([f32; 3]),
}

#[derive(Clone, Copy, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct Lifetime {
    appear_at: Option<u32>,
    remove_at: Option<u32>,
}

impl Lifetime {
    fn check(&self) -> Result<(), String> {
        if self.appear_at == Some(0) || self.remove_at == Some(0) {
            return Err("iterations are 1-based: appear_at and remove_at start at 1".into());
        }
        match (self.appear_at, self.remove_at) {
            (Some(a), Some(r)) if a >= r => {
                Err(format!("appear_at ({a}) must come before remove_at ({r})"))
            }
            _ => Ok(()),
        }
    }
}

/// Surfaces return depth unless a scene says otherwise.
fn returns_by_default() -> bool {
    true
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectFile {
    name: Option<String>,
    shape: Shape,
    size: Option<Vec<f32>>,
    radius: Option<f32>,
    height: Option<f32>,
    segments: Option<u32>,
    path: Option<String>,
    #[serde(default)]
    translation: [f32; 3],
    #[serde(default)]
    rotation: [f32; 3],
    scale: Option<Scale>,
    #[serde(default)]
    floor: bool,
    #[serde(default = "returns_by_default")]
    returns: bool,
    appear_at: Option<u32>,
    remove_at: Option<u32>,
    dynamic: Option<Lifetime>,
    motion: Option<MotionFile>,
}

#[derive(Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct MotionFile {
    by: [f32; 3],
    from: u32,
    until: u32,
}

impl MotionFile {
    fn check(&self) -> Result<Motion, String> {
        check_finite("motion.by", &self.by)?;
        if self.from == 0 {
            return Err("iterations are 1-based: motion.from starts at 1".into());
        }
        if self.from >= self.until {
            return Err(format!(
                "motion.from ({}) must come before motion.until ({})",
                self.from, self.until
            ));
        }
        Ok(Motion {
            by: Vec3::from(self.by),
            from: self.from,
            until: self.until,
        })
    }
}

impl ObjectFile {
    /// Validates everything before reading any mesh file, so a typo costs no I/O.
    fn build(
        &self,
        name: &str,
        source: &Path,
        options: &SceneOptions,
    ) -> Result<SceneObject, String> {
        let given = [
            ("size", self.size.is_some()),
            ("radius", self.radius.is_some()),
            ("height", self.height.is_some()),
            ("segments", self.segments.is_some()),
            ("path", self.path.is_some()),
        ];
        if let Some((key, _)) = given
            .iter()
            .find(|(key, g)| *g && !self.shape.keys().contains(key))
        {
            return Err(format!(
                "`{key}` does not apply to shape \"{}\"",
                self.shape.name()
            ));
        }
        check_finite("translation", &self.translation)?;
        check_finite("rotation", &self.rotation)?;
        let scale = match self.scale {
            None => Vec3::ONE,
            Some(Scale::Uniform(s)) => Vec3::splat(s),
            Some(Scale::Axes(s)) => Vec3::from(s),
        };
        check_positive("scale", &scale.to_array())?;
        let static_life = self.lifetime(false);
        static_life.check()?;
        let dynamic_life = self.lifetime(true);
        dynamic_life
            .check()
            .map_err(|m| format!("{m} (in dynamic runs)"))?;
        let motion = self.motion.map(|m| m.check()).transpose()?;

        let mut mesh = self.local_mesh(source, options)?;
        let [rx, ry, rz] = self.rotation.map(f32::to_radians);
        let rotation =
            Mat3::from_rotation_z(rz) * Mat3::from_rotation_y(ry) * Mat3::from_rotation_x(rx);
        let translation = Vec3::from(self.translation);
        // Normals go through the inverse transpose, R·S⁻¹, to stay
        // perpendicular under non-uniform scale.
        mesh.transform(
            |p| rotation * (scale * p) + translation,
            |n| rotation * (n / scale),
        );
        if mesh.positions.iter().any(|p| !p.is_finite()) {
            return Err("the transformed object does not fit in 32-bit floats (size, scale or translation too large)".into());
        }
        if mesh.normals.is_empty() {
            mesh.compute_vertex_normals();
        }
        let life = if options.dynamic {
            dynamic_life
        } else {
            static_life
        };
        Ok(SceneObject {
            name: name.to_owned(),
            mesh,
            floor: self.floor,
            returns: self.returns,
            appear_at: life.appear_at,
            remove_at: life.remove_at,
            motion,
        })
    }

    /// Dynamic runs let `dynamic`'s iterations override the object's own.
    fn lifetime(&self, dynamic: bool) -> Lifetime {
        let d = self.dynamic.filter(|_| dynamic).unwrap_or_default();
        Lifetime {
            appear_at: d.appear_at.or(self.appear_at),
            remove_at: d.remove_at.or(self.remove_at),
        }
    }

    /// The untransformed surface; a mesh file's own normals and colours are
    /// dropped because normals are recomputed after the transform.
    fn local_mesh(&self, source: &Path, options: &SceneOptions) -> Result<Mesh, String> {
        let radius = || required_positive("radius", self.radius);
        // Beyond a few thousand segments a shape only costs memory.
        const MAX_SEGMENTS: u32 = 4096;
        let segments = |default: u32, min: u32| match self.segments {
            Some(s) if s < min => Err(format!("`segments` must be at least {min}, got {s}")),
            Some(s) if s > MAX_SEGMENTS => Err(format!(
                "`segments` must be at most {MAX_SEGMENTS}, got {s}"
            )),
            s => Ok(s.unwrap_or(default)),
        };
        Ok(match self.shape {
            Shape::Cuboid => shapes::cuboid(Vec3::from(self.size::<3>()?)),
            Shape::Plane => shapes::plane(Vec2::from(self.size::<2>()?)),
            Shape::Cylinder => shapes::cylinder(
                radius()?,
                required_positive("height", self.height)?,
                segments(
                    shapes::DEFAULT_CYLINDER_SEGMENTS,
                    shapes::MIN_CYLINDER_SEGMENTS,
                )?,
            ),
            Shape::Sphere => shapes::sphere(
                radius()?,
                segments(shapes::DEFAULT_SPHERE_SEGMENTS, shapes::MIN_SPHERE_SEGMENTS)?,
            ),
            Shape::Mesh => {
                let raw = self
                    .path
                    .as_deref()
                    .ok_or("missing `path` (the mesh file)")?;
                let path = mesh_path(raw, source, &options.variables)?;
                let mut mesh = read_mesh(&path).map_err(|e| e.to_string())?;
                if mesh.is_empty() {
                    return Err(format!("{}: the mesh has no triangles", path.display()));
                }
                mesh.normals.clear();
                mesh.colors.clear();
                mesh
            }
        })
    }

    fn size<const N: usize>(&self) -> Result<[f32; N], String> {
        let size = self
            .size
            .as_deref()
            .ok_or_else(|| format!("missing `size` ({N} full extents in metres)"))?;
        let size: [f32; N] = size.try_into().map_err(|_| {
            format!(
                "`size` needs {N} numbers for this shape, got {}",
                size.len()
            )
        })?;
        check_positive("size", &size)?;
        Ok(size)
    }
}

/// Expands `${name}` from `variables`; see the module doc for how relative paths resolve.
fn mesh_path(
    raw: &str,
    source: &Path,
    variables: &BTreeMap<String, PathBuf>,
) -> Result<PathBuf, String> {
    let mut expanded = OsString::new();
    let mut rest = raw;
    while let Some(start) = rest.find("${") {
        expanded.push(&rest[..start]);
        let after = &rest[start + 2..];
        let end = after
            .find('}')
            .ok_or_else(|| format!("unterminated ${{ in path \"{raw}\""))?;
        let variable = &after[..end];
        let value = variables.get(variable).ok_or_else(|| {
            format!(
                "path \"{raw}\": ${{{variable}}} was not given: {}",
                how_to_pass(variable)
            )
        })?;
        expanded.push(value);
        rest = &after[end + 1..];
    }
    expanded.push(rest);
    let path = PathBuf::from(expanded);
    Ok(if raw.starts_with("${") {
        path
    } else {
        source.parent().unwrap_or(Path::new("")).join(path)
    })
}

fn required_positive(key: &str, value: Option<f32>) -> Result<f32, String> {
    let value = value.ok_or_else(|| format!("missing `{key}` (metres)"))?;
    check_positive(key, &[value])?;
    Ok(value)
}

fn check_positive(key: &str, values: &[f32]) -> Result<(), String> {
    match values.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
        Some(v) => Err(format!("`{key}` must be positive and finite, got {v}")),
        None => Ok(()),
    }
}

fn check_finite(key: &str, values: &[f32]) -> Result<(), String> {
    match values.iter().find(|v| !v.is_finite()) {
        Some(v) => Err(format!("`{key}` must be finite, got {v}")),
        None => Ok(()),
    }
}

/// How errors name object `index` (0-based), so users can find it by count or by name.
fn object_label(index: usize, name: Option<&str>) -> String {
    match name {
        Some(name) => format!("object {} \"{name}\"", index + 1),
        None => format!("object {}", index + 1),
    }
}

/// 1-based line number of byte `offset`.
fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// toml's own message (it shows the line), prefixed with the object it falls
/// in when the file is at least well-formed enough to find its objects.
fn describe_toml_error(text: &str, error: &toml::de::Error) -> String {
    #[derive(Deserialize)]
    struct Outline {
        #[serde(default)]
        object: Vec<Spanned<toml::Table>>,
    }
    let object = error.span().and_then(|span| {
        let outline: Outline = toml::from_str(text).ok()?;
        let (i, table) = outline
            .object
            .iter()
            .enumerate()
            .find(|(_, o)| o.span().contains(&span.start))?;
        let name = table.get_ref().get("name").and_then(|n| n.as_str());
        Some(format!("{}: ", object_label(i, name)))
    });
    format!(
        "{}{}",
        object.unwrap_or_default(),
        error.to_string().trim_end()
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::shapes::tests::assert_closed;

    const TABLE: &str = include_str!("../../../../scenes/table.toml");
    const BUNNIES: &str = include_str!("../../../../scenes/bunnies.toml");
    const EXAMPLE: &str = include_str!("../../../../scenes/example.toml");

    fn parse(text: &str) -> Result<Scene> {
        Scene::parse(
            text,
            Path::new("scenes/test.toml"),
            &SceneOptions::default(),
        )
    }

    /// The error message for `text`, which must fail.
    fn error(text: &str) -> String {
        let e = parse(text).unwrap_err();
        assert!(matches!(e, Error::Format { .. }), "{e:?}");
        let message = e.to_string();
        assert!(message.starts_with("scenes/test.toml: "), "{message}");
        message
    }

    /// A one-box scene with `extra` lines added to the box.
    fn with_box(extra: &str) -> String {
        format!("[[object]]\nname = \"crate\"\nshape = \"box\"\nsize = [1, 2, 3]\n{extra}\n")
    }

    fn object<'a>(scene: &'a Scene, name: &str) -> &'a SceneObject {
        scene.objects.iter().find(|o| o.name == name).unwrap()
    }

    #[test]
    fn table_matches_the_thesis() {
        let scene = Scene::parse(
            TABLE,
            Path::new("scenes/table.toml"),
            &SceneOptions::default(),
        )
        .unwrap();
        assert_eq!(scene.name, "table");
        assert_eq!(scene.objects.len(), 8);
        assert_eq!(scene.helix, HelixParams::default());
        let close = |a: Vec3, b: Vec3| a.abs_diff_eq(b, 1e-5);
        let floor = object(&scene, "floor").mesh.bounds();
        assert!(object(&scene, "floor").floor);
        assert!(close(floor.max, Vec3::new(5.0, 0.1, 5.0)));
        let top = object(&scene, "table top").mesh.bounds();
        assert!(close(top.min, Vec3::new(-0.5, 0.65, -0.375)));
        assert!(close(top.max, Vec3::new(0.5, 0.75, 0.375)));
        for leg in scene.objects.iter().filter(|o| o.name.starts_with("leg")) {
            let b = leg.mesh.bounds();
            // Standing on the floor, touching the top's underside, under its corners.
            assert!((b.min.y - floor.max.y).abs() < 1e-5 && (b.max.y - top.min.y).abs() < 1e-5);
            assert!((b.max.x.abs().max(b.min.x.abs()) - 0.5).abs() < 1e-5);
            assert!((b.max.z.abs().max(b.min.z.abs()) - 0.375).abs() < 1e-5);
        }
        for (name, x) in [("cup +x", 0.1875), ("cup -x", -0.1875)] {
            let b = object(&scene, name).mesh.bounds();
            assert!((b.min.y - 0.75).abs() < 1e-5 && (b.max.y - 0.87).abs() < 1e-5);
            assert!((b.center().x - x).abs() < 1e-5 && b.center().z.abs() < 1e-5);
            assert!((b.extent().x - 0.06).abs() < 1e-5);
        }
        let bounds = scene.object_bounds();
        assert!(close(bounds.min, Vec3::new(-0.5, 0.1, -0.375)));
        assert!(close(bounds.max, Vec3::new(0.5, 0.87, 0.375)));
        for o in &scene.objects {
            assert_closed(&o.mesh);
            assert!(o.present_at(1) && o.present_at(1000));
        }
        let (mesh, ids) = scene.world_mesh(1);
        assert_eq!(mesh.triangle_count(), 6 * 12 + 2 * 4 * 64);
        assert_eq!(ids.len(), mesh.triangle_count());
        assert_eq!((ids[0], ids[12], ids[ids.len() - 1]), (0, 1, 7));
        assert_eq!(mesh.normals.len(), mesh.vertex_count());
        assert_eq!(scene.full_mesh(), mesh);
    }

    #[test]
    fn bunnies_need_the_bunny_mesh() {
        let e = Scene::parse(
            BUNNIES,
            Path::new("scenes/bunnies.toml"),
            &SceneOptions::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("pass the bunny mesh with --bunny PATH (e.g. the Stanford bunny PLY)"),
            "{e}"
        );
        assert!(
            e.starts_with("scenes/bunnies.toml: object 2 \"left bunny\""),
            "{e}"
        );
        // The rest of the file is right: only the mesh is missing.
        let file: SceneFile = toml::from_str(BUNNIES).unwrap();
        assert_eq!(file.helix.params().unwrap().height, [0.75, 1.0]);
        let middle = file.object[2].get_ref();
        assert_eq!(middle.lifetime(false).appear_at, None);
        assert_eq!(middle.lifetime(true).appear_at, Some(26));
    }

    #[test]
    fn example_uses_every_key_and_parses() {
        let options = SceneOptions {
            dynamic: true,
            ..Default::default()
        };
        let scene = Scene::parse(EXAMPLE, Path::new("scenes/example.toml"), &options).unwrap();
        assert_eq!(scene.objects.len(), 4);
        let ball = object(&scene, "ball");
        assert!(!ball.present_at(9) && ball.present_at(10) && !ball.present_at(20));
        assert!(!object(&scene, "crate").returns && ball.returns);
        let post = object(&scene, "post");
        assert!(post.present_at(14) && !post.present_at(15));
        let b = post.mesh.bounds();
        assert!((b.extent().y - 1.2).abs() < 1e-5);
        // A floor plane is not what the helix goes around.
        assert!(scene.object_bounds().extent().x < 2.0);
        let (mesh, ids) = scene.world_mesh(15);
        assert!(ids.iter().all(|&i| i != 3));
        assert!(ids.contains(&2));
        assert_eq!(ids.len(), mesh.triangle_count());
        // The ball rolls 0.1 m an iteration from iteration 12 to 17.
        assert_eq!(ball.state_at(12), Some(Vec3::ZERO));
        assert!((ball.state_at(15).unwrap().x - 0.3).abs() < 1e-6);
        assert_eq!(ball.state_at(17), ball.state_at(19));
    }

    #[test]
    fn a_moving_object_is_imaged_where_it_has_got_to() {
        let scene = parse(&with_box(
            "motion = { by = [2.0, 0.0, -1.0], from = 3, until = 7 }",
        ))
        .unwrap();
        let centre = |iteration| scene.world_mesh(iteration).0.bounds().center();
        assert_eq!(centre(1), Vec3::ZERO);
        assert_eq!(centre(3), Vec3::ZERO);
        assert!((centre(5) - Vec3::new(1.0, 0.0, -0.5)).length() < 1e-5);
        assert!((centre(7) - Vec3::new(2.0, 0.0, -1.0)).length() < 1e-5);
        assert_eq!(centre(9), centre(7));
        // The placement is what the helix goes around, wherever it moves.
        assert_eq!(scene.object_bounds().center(), Vec3::ZERO);
        for (motion, says) in [
            (
                "by = [1.0, 0.0, 0.0], from = 0, until = 4",
                "motion.from starts at 1",
            ),
            (
                "by = [1.0, 0.0, 0.0], from = 4, until = 4",
                "must come before motion.until",
            ),
            ("by = [nan, 0.0, 0.0], from = 1, until = 4", "motion.by"),
            ("by = [1.0, 0.0, 0.0], from = 1", "until"),
        ] {
            let e = parse(&with_box(&format!("motion = {{ {motion} }}")))
                .unwrap_err()
                .to_string();
            assert!(e.contains(says) && e.contains("crate"), "{motion}: {e}");
        }
    }

    #[test]
    fn dynamic_lifetimes_apply_only_in_dynamic_runs() {
        let text = with_box("remove_at = 40\ndynamic = { appear_at = 26 }");
        let plain = parse(&text).unwrap();
        assert!(plain.objects[0].present_at(1) && !plain.objects[0].present_at(40));
        let options = SceneOptions {
            dynamic: true,
            ..Default::default()
        };
        let dynamic = Scene::parse(&text, Path::new("t.toml"), &options).unwrap();
        let o = &dynamic.objects[0];
        assert!(!o.present_at(25) && o.present_at(26) && o.present_at(39) && !o.present_at(40));
        assert_eq!(dynamic.name, "t");
        assert!(dynamic.world_mesh(1).0.is_empty());
    }

    #[test]
    fn transforms_scale_then_rotate_then_translate() {
        let text = with_box("scale = [2, 1, 1]\nrotation = [0, 90, 0]\ntranslation = [10, 0, 0]");
        let scene = parse(&text).unwrap();
        let mesh = &scene.objects[0].mesh;
        let b = mesh.bounds();
        // x: 1·2 → along z after 90° about y; z: 3 → along x.
        assert!(
            b.extent().abs_diff_eq(Vec3::new(3.0, 2.0, 2.0), 1e-5),
            "{}",
            b.extent()
        );
        assert!(b.center().abs_diff_eq(Vec3::new(10.0, 0.0, 0.0), 1e-5));
        assert_closed(mesh);
        for t in 0..mesh.triangle_count() {
            let [a, b, c] = mesh.corners(t);
            let n = (b - a).cross(c - a).normalize();
            let outward = ((a + b + c) / 3.0 - Vec3::new(10.0, 0.0, 0.0)).dot(n) > 0.0;
            assert!(outward, "triangle {t} faces inwards");
            for &i in &mesh.triangles[t] {
                assert!(mesh.normals[i as usize].abs_diff_eq(n, 1e-5));
            }
        }
    }

    #[test]
    fn mesh_paths_resolve_against_the_scene_or_the_caller() {
        let variables = BTreeMap::from([("models".to_string(), PathBuf::from("data/m"))]);
        let scene = Path::new("scenes/x.toml");
        let p = |raw| mesh_path(raw, scene, &variables);
        assert_eq!(p("meshes/a.ply").unwrap(), Path::new("scenes/meshes/a.ply"));
        assert_eq!(p("/abs/a.ply").unwrap(), Path::new("/abs/a.ply"));
        assert_eq!(p("${models}/a.ply").unwrap(), Path::new("data/m/a.ply"));
        assert!(p("${models").unwrap_err().contains("unterminated"));
        let e = p("${chair}").unwrap_err();
        assert!(e.contains("pass --chair PATH"), "{e}");
    }

    #[test]
    fn rejects_bad_scenes() {
        let cases: &[(&str, &str)] = &[
            ("name = \"x\"\n[[object]\n", "line 2"),
            ("name = \"x\"\n", "no [[object]]"),
            (
                "[[object]]\nshape = \"cone\"\nsize = [1, 1, 1]\n",
                "unknown variant `cone`",
            ),
            (
                "[[object]]\nname = \"a\"\nshape = \"box\"\ncolour = 1\n",
                "object 1 \"a\"",
            ),
            (
                "[[object]]\nshape = \"box\"\ncolour = 1\n",
                "unknown field `colour`",
            ),
            ("colour = 1\n", "unknown field `colour`"),
            ("[helix]\nturn = 2\n", "unknown field `turn`"),
            (
                "[[object]]\nshape = \"box\"\n",
                "object 1 (line 1): missing `size`",
            ),
            (
                "[[object]]\nshape = \"plane\"\nsize = [1, 1, 1]\n",
                "needs 2 numbers",
            ),
            ("[[object]]\nshape = \"sphere\"\n", "missing `radius`"),
            (
                "[[object]]\nshape = \"cylinder\"\nradius = 1\n",
                "missing `height`",
            ),
            (
                "[[object]]\nshape = \"sphere\"\nradius = -1\n",
                "`radius` must be positive",
            ),
            (
                "[[object]]\nshape = \"sphere\"\nradius = 1\nsegments = 2\n",
                "at least 4",
            ),
            (
                "[[object]]\nshape = \"box\"\nsize = [1, 0, 1]\n",
                "`size` must be positive",
            ),
            (
                "[[object]]\nshape = \"box\"\nsize = [1, 1, 1]\nradius = 1\n",
                "`radius` does not apply to shape \"box\"",
            ),
            ("[[object]]\nshape = \"mesh\"\n", "missing `path`"),
            (
                "[[object]]\nshape = \"mesh\"\npath = \"${bunny}\"\n",
                "--bunny PATH",
            ),
            (
                "[[object]]\nshape = \"mesh\"\npath = \"${chair}\"\n",
                "pass --chair PATH",
            ),
            (
                "[helix]\nmargin = -1\n[[object]]\nshape = \"sphere\"\nradius = 1\n",
                "[helix]: `margin`",
            ),
            (
                "[helix]\nheight = [nan, 1]\n[[object]]\nshape = \"sphere\"\nradius = 1\n",
                "`height` must be finite",
            ),
        ];
        for (text, expected) in cases {
            let e = error(text);
            assert!(e.contains(expected), "{text:?}: {e}");
        }
        let box_cases = [
            ("scale = 0", "`scale` must be positive"),
            ("scale = [1, -1, 1]", "`scale` must be positive"),
            ("scale = \"big\"", "a number or an array of three numbers"),
            ("translation = [0, inf, 0]", "`translation` must be finite"),
            ("rotation = [nan, 0, 0]", "`rotation` must be finite"),
            (
                "appear_at = 5\nremove_at = 5",
                "appear_at (5) must come before remove_at (5)",
            ),
            (
                "remove_at = 5\ndynamic = { appear_at = 9 }",
                "(in dynamic runs)",
            ),
            ("appear_at = 0", "1-based"),
            ("dynamic = { appear = 3 }", "unknown field `appear`"),
        ];
        for (extra, expected) in box_cases {
            let e = error(&with_box(extra));
            assert!(e.contains(expected), "{extra:?}: {e}");
            assert!(e.contains("object 1 \"crate\""), "{extra:?}: {e}");
        }
        // Semantic errors give the object's line too.
        let e = error(&format!("name = \"x\"\n\n{}", with_box("scale = 0")));
        assert!(e.contains("(line 3)"), "{e}");
    }

    #[test]
    fn missing_file_is_an_io_error() {
        let e = Scene::load(
            Path::new("/nonexistent/scene.toml"),
            &SceneOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(e, Error::Io { .. }));
    }
}
