//! The twin's scene: the table plane, the goal cube and up to [`MAX_OBSTACLES`]
//! axis-aligned obstacle boxes, in fixed capacity. Converts to and from the scene file
//! format of `shm_schemas::scene_file`.

use nalgebra::Vector3;
use shm_schemas::scene_file::{BoxSpec, GoalSpec, MAX_OBSTACLES, SceneFile, TableSpec};

/// Why a scene was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SceneError {
    /// More than [`MAX_OBSTACLES`] boxes.
    #[error("more than {MAX_OBSTACLES} obstacle boxes")]
    TooManyObstacles,
    /// A value was out of range (see `SceneFile::validate` for the message).
    #[error("scene values out of range (non-finite, non-positive size, or beyond the workspace)")]
    Invalid,
}

/// The goal cube.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Goal {
    /// Centre (m).
    pub center_m: [f64; 3],
    /// Edge length (m).
    pub size_m: f64,
}

/// One axis-aligned obstacle box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxObstacle {
    /// Centre (m).
    pub center_m: [f64; 3],
    /// Full extents along x, y, z (m).
    pub size_m: [f64; 3],
}

impl BoxObstacle {
    /// Height (m).
    pub fn height_m(&self) -> f64 {
        self.size_m[2]
    }

    /// Larger horizontal extent (m).
    pub fn width_m(&self) -> f64 {
        self.size_m[0].max(self.size_m[1])
    }

    /// Centre as a vector (m).
    pub fn center(&self) -> Vector3<f64> {
        Vector3::from(self.center_m)
    }

    /// Half extents as a vector (m).
    pub fn half_extents(&self) -> Vector3<f64> {
        Vector3::from(self.size_m) * 0.5
    }
}

/// Up to [`MAX_OBSTACLES`] boxes in a fixed array: `Copy`, no heap. Reads like a slice
/// (`len`, `iter`, indexing through `Deref`); grows with [`Obstacles::push`].
#[derive(Debug, Clone, Copy)]
pub struct Obstacles {
    boxes: [BoxObstacle; MAX_OBSTACLES],
    len: usize,
}

impl Obstacles {
    /// No boxes.
    pub const fn new() -> Self {
        Self {
            boxes: [BoxObstacle {
                center_m: [0.0; 3],
                size_m: [0.0; 3],
            }; MAX_OBSTACLES],
            len: 0,
        }
    }

    /// Appends a box.
    ///
    /// # Errors
    /// Gives the box back when all [`MAX_OBSTACLES`] places are taken.
    pub fn push(&mut self, b: BoxObstacle) -> Result<(), BoxObstacle> {
        match self.boxes.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len += 1;
                Ok(())
            }
            None => Err(b),
        }
    }

    /// Removes and returns the last box.
    pub fn pop(&mut self) -> Option<BoxObstacle> {
        self.len = self.len.checked_sub(1)?;
        Some(self.boxes[self.len])
    }

    /// Removes every box.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl Default for Obstacles {
    fn default() -> Self {
        Self::new()
    }
}

impl core::ops::Deref for Obstacles {
    type Target = [BoxObstacle];
    fn deref(&self) -> &[BoxObstacle] {
        &self.boxes[..self.len]
    }
}

impl core::ops::DerefMut for Obstacles {
    fn deref_mut(&mut self) -> &mut [BoxObstacle] {
        &mut self.boxes[..self.len]
    }
}

impl PartialEq for Obstacles {
    fn eq(&self, other: &Self) -> bool {
        **self == **other
    }
}

impl<'a> IntoIterator for &'a Obstacles {
    type Item = &'a BoxObstacle;
    type IntoIter = core::slice::Iter<'a, BoxObstacle>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

/// A scene in fixed capacity: `Copy`, no heap. The same value serves the lookahead, the
/// cycle's shield and the learner's environments.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// Height of the table top (m).
    pub table_height_m: f64,
    /// The goal cube.
    pub goal: Goal,
    /// Obstacle boxes.
    pub obstacles: Obstacles,
}

impl Scene {
    /// A scene with a goal and no obstacles, on a table at `table_height_m`.
    pub fn empty(table_height_m: f64, goal: Goal) -> Self {
        Self {
            table_height_m,
            goal,
            obstacles: Obstacles::new(),
        }
    }

    /// Converts (and validates) a scene file.
    ///
    /// # Errors
    /// [`SceneError`] when the file's values are out of range.
    pub fn from_file(file: &SceneFile) -> Result<Self, SceneError> {
        if file.obstacles.len() > MAX_OBSTACLES {
            return Err(SceneError::TooManyObstacles);
        }
        file.validate().map_err(|_| SceneError::Invalid)?;
        let mut obstacles = Obstacles::new();
        for b in &file.obstacles {
            obstacles
                .push(BoxObstacle {
                    center_m: b.center_m,
                    size_m: b.size_m,
                })
                .map_err(|_| SceneError::TooManyObstacles)?;
        }
        Ok(Self {
            table_height_m: file.table.height_m,
            goal: Goal {
                center_m: file.goal.center_m,
                size_m: file.goal.size_m,
            },
            obstacles,
        })
    }

    /// Converts to the scene file format (with an empty name).
    pub fn to_file(&self) -> SceneFile {
        SceneFile {
            name: String::new(),
            table: TableSpec {
                height_m: self.table_height_m,
            },
            goal: GoalSpec {
                center_m: self.goal.center_m,
                size_m: self.goal.size_m,
            },
            obstacles: self
                .obstacles
                .iter()
                .map(|b| BoxSpec {
                    center_m: b.center_m,
                    size_m: b.size_m,
                    path: Default::default(),
                })
                .collect(),
        }
    }

    /// The point the TCP must reach: `hover_m` above the goal cube's top face.
    pub fn goal_target_m(&self, hover_m: f64) -> Vector3<f64> {
        let g = &self.goal;
        Vector3::new(
            g.center_m[0],
            g.center_m[1],
            g.center_m[2] + g.size_m / 2.0 + hover_m,
        )
    }
}
