//! `m6p-twin icd`: the ICD as data, from the twin's own wire types.

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Only this node (FC, PC, EPS, ECU, COMM, payload).
    pub node: Option<String>,
    /// JSON (format 1) instead of text, for tools and codecs.
    #[arg(long, conflicts_with = "node")]
    pub json: bool,
    /// The Markdown tables of docs/protocol.md.
    #[arg(long, conflicts_with_all = ["node", "json"])]
    pub markdown: bool,
    /// An XTCE 1.2 mission database for YAMCS and other XTCE tools (docs/operations.md).
    #[arg(long, conflicts_with_all = ["node", "json", "markdown"])]
    pub xtce: bool,
}

pub fn cmd_icd(a: Args) -> anyhow::Result<bool> {
    if a.xtce {
        print!("{}", m6p_twin::icd::xtce::to_xtce().xml);
    } else if a.markdown {
        print!("{}", m6p_twin::icd::to_markdown());
    } else if a.json {
        println!("{}", m6p_twin::icd::to_json());
    } else {
        print!("{}", m6p_twin::icd::to_text(a.node.as_deref())?);
    }
    Ok(true)
}
