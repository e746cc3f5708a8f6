//! `DIR/identity.csv` of `eval map`: where an object's map id changed and which ids stood for two
//! objects, window by window, so the identity figures of the summary can be traced to the
//! instances (and the fold rules) behind them.

use std::path::Path;

use anyhow::{Context, Result};
use groupforward_harness::eval::score::{identity_events, TruthObject, WindowRecord};

/// The header of `identity.csv`. `event`: `fold` (the window folded the previous id into the new
/// one), `rematch` (the object is found under another instance), `shared` (the id was found as
/// each of `objects`, space separated; no window, no previous id).
const HEADER: &str = "scene,window,objects,classes,event,previous_id,id";

/// The rows of one scene's run (`windows` as the run recorded them), scored like the summary's
/// map id changes and ids on two objects (objects seen by at least `min_pixels`).
pub fn identity_rows(
    scene: &str,
    objects: &[TruthObject],
    windows: &[WindowRecord],
    min_pixels: u64,
) -> Vec<String> {
    let class = |id: u16| {
        objects
            .iter()
            .find(|o| o.id == id)
            .map_or("?", |o| o.class.as_str())
            .to_owned()
    };
    let (_, changes, ids) = identity_events(objects, windows, min_pixels);
    let changed = changes.into_iter().map(|c| {
        let event = if c.folded { "fold" } else { "rematch" };
        let (object, class) = (c.object, class(c.object));
        format!(
            "{scene},{},{object},{class},{event},{},{}",
            c.window, c.previous_id, c.id
        )
    });
    let shared = ids.into_iter().filter(|(_, o)| o.len() > 1).map(|(id, o)| {
        let objects: Vec<String> = o.iter().map(u16::to_string).collect();
        let classes: Vec<String> = o.iter().map(|&k| class(k)).collect();
        format!(
            "{scene},,{},{},shared,,{id}",
            objects.join(" "),
            classes.join(" ")
        )
    });
    changed.chain(shared).collect()
}

/// Write `rows` ([`identity_rows`] of every scene) to `path` under [`HEADER`].
pub fn write_identity_csv(path: &Path, rows: &[String]) -> Result<()> {
    let text: String = std::iter::once(HEADER)
        .chain(rows.iter().map(String::as_str))
        .flat_map(|line| [line, "\n"])
        .collect();
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
