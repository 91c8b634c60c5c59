//! `m6p-twin schema`: the JSON schema of the scenario or campaign format.

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The campaign file's schema instead of the scenario's.
    #[arg(long)]
    pub campaign: bool,
}

pub fn cmd_schema(campaign: bool) -> anyhow::Result<bool> {
    let schema = if campaign {
        schemars::schema_for!(m6p_twin::campaign::CampaignSpec)
    } else {
        m6p_twin::scenario::schema()
    };
    println!("{}", serde_json::to_string_pretty(&schema)?);
    Ok(true)
}
