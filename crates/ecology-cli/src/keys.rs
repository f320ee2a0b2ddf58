//! `ecology keys`: create an ecology's certificate authority, add members, grant remote sets, list
//! who may do what. Every networked command then takes `--keys DIR`.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use ecology_tuples::PeisId;
use ecology_zenoh::security::{
    CA_CERT_FILE, CA_KEY_FILE, EXECUTIVE_KEYS, GrantPattern, KeysDir, ROSTER_FILE, Role,
};

use crate::{EXIT_BAD_INPUT, EXIT_OK};

/// Arguments of `ecology keys`.
#[derive(Debug, Args)]
pub struct KeysArgs {
    #[command(subcommand)]
    command: KeysCommand,
}

#[derive(Debug, Subcommand)]
enum KeysCommand {
    /// Create a new ecology in DIR: its certificate authority and an empty roster.
    Init {
        /// The keys directory to create.
        dir: PathBuf,
    },
    /// Add members: a certificate signed by the ecology for each, listed in the roster.
    Add {
        /// The keys directory (made by `ecology keys init`).
        dir: PathBuf,
        /// The PEIS names to add.
        #[arg(required = true)]
        names: Vec<String>,
        /// What they are: peis (owns its tuples), executive (may also switch components on and
        /// off and wire them), router (trusted to forward).
        #[arg(long, default_value = "peis")]
        role: Role,
    },
    /// Let REQUESTER remote-set keys matching PATTERN of every PEIS (or of --owner).
    Grant {
        /// The keys directory.
        dir: PathBuf,
        /// Who may ask.
        requester: String,
        /// Dotted key patterns: `*` one segment, `**` any, `mi-*` a segment starting `mi-`.
        #[arg(required = true)]
        patterns: Vec<String>,
        /// Only this PEIS's keys.
        #[arg(long, value_name = "PEIS")]
        owner: Option<String>,
    },
    /// List the members and what each may set on others.
    List {
        /// The keys directory.
        dir: PathBuf,
    },
}

/// Runs `ecology keys`.
pub fn keys(args: &KeysArgs) -> anyhow::Result<u8> {
    match &args.command {
        KeysCommand::Init { dir } => {
            KeysDir::init(dir)?;
            println!(
                "created a new ecology in {}: {CA_CERT_FILE} (give it to every device), \
                 {CA_KEY_FILE} (keep it here: it signs new members), {ROSTER_FILE} (the roster)",
                dir.display()
            );
            println!(
                "next: ecology keys add {} NAME… (and one with --role executive)",
                dir.display()
            );
            Ok(EXIT_OK)
        }
        KeysCommand::Add { dir, names, role } => {
            let mut keys = KeysDir::open(dir)?;
            let names = match names
                .iter()
                .map(|n| PeisId::new(n))
                .collect::<Result<Vec<_>, _>>()
            {
                Ok(names) => names,
                Err(e) => {
                    eprintln!("error: {e}");
                    return Ok(EXIT_BAD_INPUT);
                }
            };
            for name in names {
                keys.add(name.clone(), *role)?;
                println!(
                    "added {name} ({role}): copy {CA_CERT_FILE}, {ROSTER_FILE}, {name}.crt and {name}.key to its device"
                );
            }
            println!(
                "the roster changed: give the new {ROSTER_FILE} to every device (a process reads it when it starts)"
            );
            Ok(EXIT_OK)
        }
        KeysCommand::Grant {
            dir,
            requester,
            patterns,
            owner,
        } => {
            let mut keys = KeysDir::open(dir)?;
            let parsed = (|| {
                let requester = PeisId::new(requester).map_err(|e| e.to_string())?;
                let owner = owner
                    .as_deref()
                    .map(PeisId::new)
                    .transpose()
                    .map_err(|e| e.to_string())?;
                let patterns = patterns
                    .iter()
                    .map(|p| GrantPattern::new(p).map_err(|e| e.to_string()))
                    .collect::<Result<Vec<_>, _>>()?;
                Ok::<_, String>((requester, owner, patterns))
            })();
            let (requester, owner, patterns) = match parsed {
                Ok(parsed) => parsed,
                Err(e) => {
                    eprintln!("error: {e}");
                    return Ok(EXIT_BAD_INPUT);
                }
            };
            if keys.roster().member(&requester).is_none() {
                eprintln!(
                    "error: {requester} is not a member of the ecology in {} (add it first)",
                    dir.display()
                );
                return Ok(EXIT_BAD_INPUT);
            }
            let whose = owner
                .as_ref()
                .map_or("every PEIS".to_owned(), |o| o.to_string());
            let list: Vec<&str> = patterns.iter().map(GrantPattern::as_str).collect();
            keys.grant(requester.clone(), owner, patterns.clone())?;
            println!(
                "{requester} may now remote-set {} of {whose}; give the new {ROSTER_FILE} to every device",
                list.join(", ")
            );
            Ok(EXIT_OK)
        }
        KeysCommand::List { dir } => {
            let keys = KeysDir::open(dir)?;
            let roster = keys.roster();
            println!(
                "the ecology under {} in {}: {} members",
                roster.authority,
                dir.display(),
                roster.members.len()
            );
            for member in &roster.members {
                let mut sets: Vec<String> = Vec::new();
                if member.role == Role::Executive {
                    sets.extend(EXECUTIVE_KEYS.iter().map(|k| format!("{k} of every PEIS")));
                }
                for grant in roster.grants.iter().filter(|g| g.requester == member.name) {
                    let whose = grant
                        .owner
                        .as_ref()
                        .map_or("every PEIS".to_owned(), |o| o.to_string());
                    for key in &grant.keys {
                        sets.push(format!("{} of {whose}", key.as_str()));
                    }
                }
                let sets = if sets.is_empty() {
                    "nothing of others".to_owned()
                } else {
                    sets.join(", ")
                };
                println!(
                    "  {:<16} {:<10} may set {sets}",
                    member.name.to_string(),
                    member.role.to_string()
                );
            }
            Ok(EXIT_OK)
        }
    }
}
