//! The `eyekey` command line: the same pipeline as the service, offline, on files.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};

use crate::display::DisplayGeometry;
use crate::imaging;
use crate::observer::{plain_light_field_for_image, Observer};
use crate::optics::profile::VisionProfile;
use crate::optics::zernike::{Prescription, ZernikeCoefficients};
use crate::transport::{EyePosition, TransportOptions};

/// eyekey: show a document on a light-field display so that only one enrolled person can read it.
#[derive(Parser, Debug)]
#[command(name = "eyekey", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Print example JSON to start from.
    #[command(subcommand)]
    Example(ExampleCommand),
    /// Render what a person sees of an image shown plainly on the display, or of a frame bundle.
    Simulate(SimulateArgs),
}

/// `eyekey example ...`
#[derive(Subcommand, Debug)]
pub enum ExampleCommand {
    /// A display description.
    Display {
        /// Preset: paper, secure or small.
        #[arg(long, default_value = "paper")]
        preset: String,
    },
    /// A vision profile (no options: a perfect eye, standard observer, 6 mm pupil).
    Profile(ExampleProfileArgs),
    /// A test document: lines of text, black on white, as a PNG.
    Document {
        /// A line of text (repeat for more lines); digits, letters and : - . , #.
        #[arg(long, default_value = "PIN 4821")]
        text: Vec<String>,
        /// Width in pixels.
        #[arg(long, default_value_t = 200)]
        width: u32,
        /// Height in pixels.
        #[arg(long, default_value_t = 200)]
        height: u32,
        /// Pixels per font dot.
        #[arg(long, default_value_t = 4)]
        scale: u32,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Options of `eyekey example profile`.
#[derive(Args, Debug)]
pub struct ExampleProfileArgs {
    /// Spherical refractive error, dioptres.
    #[arg(long, allow_hyphen_values = true)]
    pub sphere: Option<f64>,
    /// Cylinder, dioptres.
    #[arg(long, allow_hyphen_values = true, requires = "axis")]
    pub cylinder: Option<f64>,
    /// Cylinder axis, degrees.
    #[arg(long)]
    pub axis: Option<f64>,
    /// Pupil diameter, mm.
    #[arg(long, default_value_t = 6.0)]
    pub pupil: f64,
    /// Print a person sampled from the population statistics with this seed instead.
    #[arg(long, conflicts_with_all = ["sphere", "cylinder", "axis"])]
    pub population_seed: Option<u64>,
}

/// Options of `eyekey simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Display description (JSON).
    #[arg(long)]
    pub display: PathBuf,
    /// The viewer's vision profile (JSON).
    #[arg(long)]
    pub profile: PathBuf,
    /// An image shown plainly (every view of a hole equal).
    #[arg(long, conflicts_with = "frames", required_unless_present = "frames")]
    pub image: Option<PathBuf>,
    /// A frame bundle directory (or .zip) written by `eyekey encode` or downloaded from the service.
    #[arg(long)]
    pub frames: Option<PathBuf>,
    /// Output PNG (sRGB).
    #[arg(long)]
    pub out: PathBuf,
    /// Lateral eye offset, mm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub eye_x: f64,
    /// Vertical eye offset, mm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub eye_y: f64,
    /// Sub-rays per light-field sample.
    #[arg(long, default_value_t = 16)]
    pub sub_rays: u32,
    /// Retinal pixels per hole pitch.
    #[arg(long, default_value_t = 2)]
    pub oversample: u32,
}

/// Reads and validates a display description.
pub fn read_display(path: &Path) -> Result<DisplayGeometry> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read display {}", path.display()))?;
    let d: DisplayGeometry =
        serde_json::from_str(&text).with_context(|| format!("display {}: malformed JSON", path.display()))?;
    d.validate().with_context(|| format!("display {}", path.display()))?;
    Ok(d)
}

/// Reads and validates a vision profile.
pub fn read_profile(path: &Path) -> Result<VisionProfile> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read profile {}", path.display()))?;
    VisionProfile::from_json(&text).with_context(|| format!("profile {}", path.display()))
}

/// Runs the command line; errors are reported by `main` on one line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Example(ExampleCommand::Display { preset }) => {
            let d = DisplayGeometry::preset(&preset)?;
            println!("{}", serde_json::to_string_pretty(&d)?);
        }
        Command::Example(ExampleCommand::Profile(a)) => {
            println!("{}", serde_json::to_string_pretty(&example_profile(&a)?)?);
        }
        Command::Example(ExampleCommand::Document { text, width, height, scale, out }) => {
            if !(8..=4096).contains(&width) || !(8..=4096).contains(&height) {
                bail!("--width and --height must be within 8..=4096 pixels");
            }
            let lines: Vec<&str> = text.iter().map(String::as_str).collect();
            imaging::save_rgb_png(&crate::glyphs::render_text(&lines, width, height, scale), &out)?;
        }
        Command::Simulate(a) => simulate(&a)?,
    }
    Ok(())
}

fn example_profile(a: &ExampleProfileArgs) -> Result<VisionProfile> {
    if !(2.0..=9.0).contains(&a.pupil) {
        bail!("--pupil must be within 2..=9 mm, got {}", a.pupil);
    }
    if let Some(seed) = a.population_seed {
        let p = crate::population::sample_population(1, seed, Default::default()).remove(0);
        p.validate()?;
        return Ok(p);
    }
    let mut p = VisionProfile { pupil_diameter_mm: a.pupil, ..VisionProfile::perfect() };
    if a.sphere.is_some() || a.cylinder.is_some() {
        let rx = Prescription {
            sphere_d: a.sphere.unwrap_or(0.0),
            cylinder_d: a.cylinder.unwrap_or(0.0),
            axis_deg: a.axis.unwrap_or(0.0),
        };
        rx.validate()?;
        // The refractive error goes into the Zernike terms directly, as an aberrometer would report it.
        let z = ZernikeCoefficients::from_prescription(&rx, a.pupil);
        for j in 3..=5 {
            p.zernike_um[j] = z.get(j);
        }
    }
    p.validate()?;
    Ok(p)
}

fn simulate(a: &SimulateArgs) -> Result<()> {
    let display = read_display(&a.display)?;
    let profile = read_profile(&a.profile)?;
    let options = TransportOptions { sub_rays: a.sub_rays, retina_oversample: a.oversample, ..Default::default() };
    let eye = EyePosition { x_mm: a.eye_x, y_mm: a.eye_y, dz_mm: 0.0 };
    let observer = Observer::new(&display, &profile, eye, &options)?;
    let l = match (&a.image, &a.frames) {
        (Some(img), _) => plain_light_field_for_image(&display, &imaging::load_image(img)?),
        (None, Some(_bundle)) => bail!("--frames needs a frame bundle reader, which this build does not have yet"),
        (None, None) => bail!("give --image or --frames"),
    };
    let view = observer.view(&l);
    imaging::save_rgb_png(&observer.picture(&view), &a.out)?;
    eprintln!(
        "wrote {} ({}×{} retinal pixels; {:.1} % of traced rays entered the pupil)",
        a.out.display(),
        observer.transport.grid.width,
        observer.transport.grid.height,
        100.0 * observer.transport.stats.sub_rays_in_pupil as f64 / observer.transport.stats.sub_rays_traced as f64
    );
    Ok(())
}
