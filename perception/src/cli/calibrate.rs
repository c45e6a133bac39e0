//! `perception calibrate`: the four workspace-corner pixels (given with `--corners`, or
//! found from the tape) plus the intrinsics and the workspace rectangle → a calibration file
//! and the rectified top view. Prints one JSON object:
//! `{"calibration","rectified","corners_px","camera_eye_m","reprojection_error_px","frame_id","calibrated_at"}`.
//!
//! The file names the camera it was made for (`[camera]`, [`perception::camera_id`]):
//! `--frame-id` (the `header.frame_id` of the camera's colour images), else the `[camera]`
//! table of the `--camera` file when it is an earlier calibration, else the synthetic
//! camera's id when the intrinsics are a synthetic camera's (no `--camera`, or a synthetic
//! camera file); otherwise `--frame-id` is required. `--calibrated-at` defaults to now.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use perception::annotate::write_image;
use perception::calibration::{
    Calibration, CalibrationFile, DEFAULT_TAPE_HSV, HsvRange, find_workspace_corners,
};
use perception::camera_id::{CalibratedAt, CalibrationCamera, SYNTHETIC_CAMERA_FRAME_ID};
use perception::frame::read_colour;
use perception::geometry::Intrinsics;
use perception::synthetic::SyntheticCamera;
use perception::workspace::WorkspaceRect;
use shm_schemas::cli_bounds::f64_within;

use super::shared::asset;

/// `perception calibrate`
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// Colour image of the table.
    #[arg(long)]
    image: PathBuf,
    /// Corner pixels "u,v u,v u,v u,v" in the order (xmin,ymin) (xmin,ymax) (xmax,ymax)
    /// (xmax,ymin); found from the tape when absent.
    #[arg(long)]
    corners: Option<String>,
    /// TOML with an [intrinsics] table (and optionally [workspace]): a synthetic camera
    /// file or an earlier calibration.
    #[arg(long)]
    camera: Option<PathBuf>,
    /// Workspace corner with the smallest x and y, "x,y" (m).
    #[arg(long)]
    workspace_min: Option<String>,
    /// Workspace size "dx,dy" (m).
    #[arg(long)]
    workspace_size: Option<String>,
    /// Table height (m).
    #[arg(long, value_parser = f64_within(-0.5, 2.0), allow_negative_numbers = true)]
    table_height: Option<f64>,
    /// Tape colour range "h,s,v-h,s,v" (OpenCV HSV scale).
    #[arg(long)]
    tape_hsv: Option<String>,
    /// The camera's frame id: the `header.frame_id` of its colour images (e.g. `ros2 topic
    /// echo --once --field header.frame_id /zed/zed_node/rgb/image_rect_color`). A live
    /// camera is driven only with a calibration naming its frame id. Default: the
    /// `[camera]` of the --camera file (an earlier calibration), else the synthetic camera's
    /// when the intrinsics are the synthetic camera's.
    #[arg(long)]
    frame_id: Option<String>,
    /// The camera's serial number (recorded for people, not checked).
    #[arg(long)]
    serial: Option<String>,
    /// When the calibration was made: RFC 3339 with offset (2026-11-27T12:53:48Z) or unix
    /// seconds. Default: now.
    #[arg(long, value_parser = parse_calibrated_at)]
    calibrated_at: Option<CalibratedAt>,
    /// Output calibration file.
    #[arg(long, default_value = "calibration.toml")]
    out: PathBuf,
    /// Output rectified view.
    #[arg(long, default_value = "rectified.png")]
    rectified: PathBuf,
}

/// Solves the calibration, writes both files and prints the summary.
pub fn run(args: CalibrateArgs) -> Result<()> {
    let cam_path = args
        .camera
        .clone()
        .unwrap_or_else(|| asset("synthetic_camera.toml"));
    let (intrinsics, file_workspace, file_camera) = read_camera_file(&cam_path)?;
    let camera = camera_identity(&args, &cam_path, file_camera)?;
    let workspace = workspace(&args, file_workspace)?;
    let bgr = read_colour(&args.image)?;
    let corners_px = match &args.corners {
        Some(c) => parse_corners(c)?,
        None => find_workspace_corners(&bgr, tape_range(args.tape_hsv.as_deref())?)?,
    };
    let cal = Calibration::new(CalibrationFile {
        camera,
        intrinsics,
        workspace,
        corners_px,
        rectified_px_per_m: 1000.0,
    })?;
    cal.save(&args.out)?;
    write_image(&args.rectified, &cal.rectify(&bgr)?)?;
    println!(
        "{}",
        serde_json::json!({
            "calibration": args.out.display().to_string(),
            "rectified": args.rectified.display().to_string(),
            "corners_px": cal.file.corners_px,
            "camera_eye_m": cal.model.pose.eye_m().as_slice(),
            "reprojection_error_px": (cal.reprojection_error_px * 1e4).round() / 1e4,
            "frame_id": cal.file.camera.frame_id,
            "calibrated_at": cal.file.camera.calibrated_at.to_string(),
        })
    );
    Ok(())
}

/// `--calibrated-at`.
fn parse_calibrated_at(s: &str) -> Result<CalibratedAt, String> {
    CalibratedAt::parse(s).map_err(|e| e.to_string())
}

/// The camera the calibration is made for: `--frame-id` (and `--serial`), else the
/// `[camera]` table of the camera file (an earlier calibration), else the synthetic camera
/// when the camera file describes it; `--calibrated-at`, else now.
fn camera_identity(
    args: &CalibrateArgs,
    cam_path: &Path,
    from_file: Option<CalibrationCamera>,
) -> Result<CalibrationCamera> {
    let calibrated_at = args.calibrated_at.unwrap_or_else(CalibratedAt::now);
    let (frame_id, serial) = match (&args.frame_id, from_file) {
        (Some(id), _) => (id.clone(), args.serial.clone()),
        (None, Some(c)) => (c.frame_id, args.serial.clone().or(c.serial)),
        (None, None) if SyntheticCamera::load(cam_path).is_ok() => {
            (SYNTHETIC_CAMERA_FRAME_ID.to_owned(), args.serial.clone())
        }
        (None, None) => bail!(
            "--frame-id is needed: {} names no camera ([camera] frame_id) and is not a synthetic \
             camera file; give the header.frame_id of the camera's colour images (e.g. `ros2 topic \
             echo --once --field header.frame_id /zed/zed_node/rgb/image_rect_color`)",
            cam_path.display()
        ),
    };
    let camera = CalibrationCamera {
        frame_id,
        serial,
        calibrated_at,
    };
    camera
        .validate(CalibratedAt::now())
        .context("--frame-id / --serial / --calibrated-at")?;
    Ok(camera)
}

/// The `[intrinsics]` table, the optional `[workspace]` table and the optional `[camera]`
/// table of a camera or calibration file.
fn read_camera_file(
    path: &Path,
) -> Result<(Intrinsics, Option<WorkspaceRect>, Option<CalibrationCamera>)> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let value: toml::Table =
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let intrinsics: Intrinsics = value
        .get("intrinsics")
        .cloned()
        .context("no [intrinsics] table")?
        .try_into()
        .with_context(|| format!("[intrinsics] of {}", path.display()))?;
    let workspace = match value.get("workspace") {
        Some(w) => Some(
            w.clone()
                .try_into()
                .with_context(|| format!("[workspace] of {}", path.display()))?,
        ),
        None => None,
    };
    let camera = match value.get("camera") {
        Some(c) => Some(
            c.clone()
                .try_into()
                .with_context(|| format!("[camera] of {}", path.display()))?,
        ),
        None => None,
    };
    Ok((intrinsics, workspace, camera))
}

/// The workspace from the flags (both `--workspace-min` and `--workspace-size`), else from
/// the camera file; `--table-height` overrides the height either way.
fn workspace(args: &CalibrateArgs, from_file: Option<WorkspaceRect>) -> Result<WorkspaceRect> {
    let mut ws = from_file;
    if let (Some(m), Some(s)) = (&args.workspace_min, &args.workspace_size) {
        ws = Some(WorkspaceRect {
            min_xy_m: pair(m, "--workspace-min")?,
            size_m: pair(s, "--workspace-size")?,
            table_height_m: args.table_height.unwrap_or(0.0),
        });
    }
    let mut ws = ws.context(
        "no workspace: give --workspace-min and --workspace-size or a [workspace] table",
    )?;
    if let Some(t) = args.table_height {
        ws.table_height_m = t;
    }
    Ok(ws)
}

/// `--corners "u,v u,v u,v u,v"`.
fn parse_corners(s: &str) -> Result<[[f64; 2]; 4]> {
    let pts: Vec<[f64; 2]> = s
        .split_whitespace()
        .map(|p| pair(p, "--corners"))
        .collect::<Result<_>>()?;
    <[[f64; 2]; 4]>::try_from(pts)
        .map_err(|v| anyhow::anyhow!("--corners: expected 4 points, got {}", v.len()))
}

/// `--tape-hsv "h,s,v-h,s,v"`, or the default tape colour.
fn tape_range(s: Option<&str>) -> Result<HsvRange> {
    let Some(s) = s else {
        return Ok(DEFAULT_TAPE_HSV);
    };
    let (a, b) = s
        .split_once('-')
        .context("--tape-hsv: expected \"h,s,v-h,s,v\"")?;
    Ok(HsvRange {
        hsv_min: triple_u8(a, "--tape-hsv")?,
        hsv_max: triple_u8(b, "--tape-hsv")?,
    })
}

/// Two comma-separated numbers, `what` naming the flag in errors.
fn pair(s: &str, what: &str) -> Result<[f64; 2]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{what}: expected \"a,b\", got {s:?}"))?;
    match v.as_slice() {
        [a, b] => Ok([*a, *b]),
        _ => bail!("{what}: expected two numbers, got {s:?}"),
    }
}

/// Three comma-separated bytes, `what` naming the flag in errors.
fn triple_u8(s: &str, what: &str) -> Result<[u8; 3]> {
    let v: Vec<u8> = s
        .split(',')
        .map(|x| x.trim().parse::<u8>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{what}: expected \"h,s,v\", got {s:?}"))?;
    match v.as_slice() {
        [a, b, c] => Ok([*a, *b, *c]),
        _ => bail!("{what}: expected three numbers, got {s:?}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: CalibrateArgs,
    }

    fn args(extra: &[&str]) -> CalibrateArgs {
        Cli::try_parse_from([&["calibrate", "--image", "x.png"][..], extra].concat())
            .unwrap()
            .args
    }

    /// Issue 30 item 2: the file names the camera: `--frame-id`, else an earlier
    /// calibration's `[camera]`, else the synthetic camera for a synthetic camera file;
    /// else `--frame-id` is asked for.
    #[test]
    fn the_calibration_names_its_camera() {
        let synthetic_cam = asset("synthetic_camera.toml");
        let c = camera_identity(&args(&[]), &synthetic_cam, None).unwrap();
        assert_eq!(c.frame_id, SYNTHETIC_CAMERA_FRAME_ID);
        assert!((c.calibrated_at.unix_s() - CalibratedAt::now().unix_s()).abs() < 60);
        let a = args(&[
            "--frame-id",
            "zed_left_camera_frame_optical",
            "--serial",
            "38492711",
            "--calibrated-at",
            "2026-11-27T12:53:48Z",
        ]);
        let c = camera_identity(&a, &synthetic_cam, None).unwrap();
        assert_eq!(
            (
                c.frame_id.as_str(),
                c.serial.as_deref(),
                c.calibrated_at.to_string()
            ),
            (
                "zed_left_camera_frame_optical",
                Some("38492711"),
                "2026-11-27T12:53:48Z".to_owned()
            )
        );
        // An earlier calibration's camera is kept (a new date).
        let c2 = camera_identity(&args(&[]), Path::new("earlier.toml"), Some(c.clone())).unwrap();
        assert_eq!((c2.frame_id, c2.serial), (c.frame_id, c.serial));
        // A camera file that names no camera and is no synthetic camera.
        let e = camera_identity(&args(&[]), Path::new("/nonexistent/zed.toml"), None)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--frame-id is needed") && e.contains("zed.toml"),
            "{e}"
        );
        let e = format!(
            "{:#}",
            camera_identity(&args(&["--frame-id", "a b"]), &synthetic_cam, None).unwrap_err()
        );
        assert!(e.contains("camera.frame_id"), "{e}");
        assert!(
            Cli::try_parse_from(["calibrate", "--image", "x.png", "--calibrated-at", "soon"])
                .is_err()
        );
    }

    #[test]
    fn flag_values_parse_or_name_the_flag() {
        assert_eq!(pair(" 0.1, -0.2", "--x").unwrap(), [0.1, -0.2]);
        assert!(format!("{:#}", pair("1", "--x").unwrap_err()).contains("--x"));
        assert!(format!("{:#}", pair("a,b", "--x").unwrap_err()).contains("--x"));
        assert_eq!(
            parse_corners("1,2 3,4 5,6 7,8").unwrap(),
            [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 8.0]]
        );
        assert!(
            parse_corners("1,2 3,4")
                .unwrap_err()
                .to_string()
                .contains("expected 4 points")
        );
        assert_eq!(tape_range(None).unwrap(), DEFAULT_TAPE_HSV);
        let t = tape_range(Some("10,20,30-40,50,60")).unwrap();
        assert_eq!((t.hsv_min, t.hsv_max), ([10, 20, 30], [40, 50, 60]));
        assert!(tape_range(Some("10,20,30")).is_err());
        assert!(tape_range(Some("10,20-40,50,60")).is_err());
    }
}
