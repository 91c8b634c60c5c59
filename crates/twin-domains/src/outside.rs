//! Links to programs outside the twin, the scenario's side: which addresses a link may
//! hold, which twin nodes it replaces, its limits; validated and compiled into the run's
//! [`KissLink`]s, SocketCAN bridges and [`OutsideLink`]s (what faults and power act on).
//!
//! The rules (docs/security.md):
//! - a KISS link sits on one segment, decided by its addresses' range (INTERPRETATION.md
//!   section 1); its `addrs` are claimed when a program connects, and a link with
//!   `addrs` refuses packets from any other source. Without `addrs` it learns them;
//! - an address held by a node of the twin cannot be a link's unless the link
//!   `replaces` that node, which is then not started;
//! - a node sitting on two media (the PC on both buses, a COMM with its radio) cannot be
//!   replaced over KISS; the PC can be over two `socketcan` links, one per bus.

use links::kiss_tcp::{KissLimits, KissLinkConfig};
use platform::addr::Segment;

use twin_core::network::{NetworkSpec, Role};
use twin_runtime::{KissLink, KissMode, OutsideLink, RunOptions, SocketCanBus};
use twin_scenario::scenario::{LinkKind, LinkSpec, PathStep, Scenario};

fn key(k: &str) -> PathStep {
    PathStep::Key(k.to_owned())
}

/// The bus a `socketcan` link's `addr` (`vcan0`, `vcan0:payload`) bridges.
fn socketcan_bus(l: &LinkSpec) -> Option<SocketCanBus> {
    SocketCanBus::parse_arg(&l.addr).ok().map(|(_, b)| b)
}

/// Check link `i` of `s` (addresses, replaced nodes, limits); its address syntax, name
/// and power channel are checked with the scenario.
pub fn validate(
    s: &Scenario,
    net: &NetworkSpec,
    i: usize,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    let Some(l) = s.links.get(i) else { return };
    let p = |f: &str| vec![key("links"), PathStep::Index(i), key(f)];
    if l.kind == LinkKind::Uart {
        validate_uart(s, l, net, &p, err);
        return;
    }
    for (f, set) in [("node", l.node.is_some()), ("pty", l.pty.is_some())] {
        if set {
            err(
                p(f),
                "only a `uart` link (a node's console) has this".to_owned(),
            );
        }
    }
    let kiss = l.kind != LinkKind::Socketcan;
    let replaced_addrs = check_replaces(s, net, i, kiss, err);
    if kiss {
        check_kiss_fields(l, net, i, &replaced_addrs, &p, err);
    } else {
        check_socketcan_fields(l, &p, err);
    }
}

/// Link `i`'s `replaces`: nodes an outside program may take the place of; their addresses.
fn check_replaces(
    s: &Scenario,
    net: &NetworkSpec,
    i: usize,
    kiss: bool,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) -> Vec<u8> {
    let Some(l) = s.links.get(i) else {
        return Vec::new();
    };
    let mut replaced_addrs = Vec::new();
    for (j, name) in l.replaces.iter().enumerate() {
        let at = || {
            vec![
                key("links"),
                PathStep::Index(i),
                key("replaces"),
                PathStep::Index(j),
            ]
        };
        let Some(node) = net.nodes.iter().find(|n| n.name.eq_ignore_ascii_case(name)) else {
            let names: Vec<&str> = net.nodes.iter().map(|n| n.name.as_str()).collect();
            err(
                at(),
                format!("unknown node `{name}` (nodes: {})", names.join(", ")),
            );
            continue;
        };
        replaced_addrs.push(node.addr);
        let why = match (node.role, kiss, socketcan_bus(l)) {
            (Role::CommPrimary | Role::CommSecondary, _, _) => Some(
                "a COMM carries the twin's UHF radio: it cannot be replaced by an outside program"
                    .to_owned(),
            ),
            (Role::Pc, true, _) => Some(
                "the PC sits on both CAN buses and a KISS link joins one segment: replace it \
                 with two socketcan links, one per bus"
                    .to_owned(),
            ),
            (Role::Ground, false, _) => Some(format!(
                "{} is on the ground segment, not on a CAN bus",
                node.name
            )),
            (Role::Payload, false, Some(SocketCanBus::Main))
            | (Role::Fc | Role::Eps | Role::Ecu, false, Some(SocketCanBus::Payload)) => {
                Some(format!("{} is not on the bus this link bridges", node.name))
            }
            _ => None,
        };
        if let Some(why) = why {
            err(at(), why);
            continue;
        }
        let others =
            s.links.iter().enumerate().filter(|&(k, o)| {
                k != i && o.replaces.iter().any(|r| r.eq_ignore_ascii_case(name))
            });
        for (k, o) in others {
            let two_buses = node.role == Role::Pc
                && !kiss
                && o.kind == LinkKind::Socketcan
                && socketcan_bus(o) != socketcan_bus(l);
            if !two_buses && k > i {
                err(
                    at(),
                    format!("{} is also replaced by links[{k}]", node.name),
                );
            }
        }
        if node.role == Role::Pc {
            let buses: Vec<_> = s
                .links
                .iter()
                .filter(|o| {
                    o.kind == LinkKind::Socketcan
                        && o.replaces.iter().any(|r| r.eq_ignore_ascii_case(name))
                })
                .filter_map(socketcan_bus)
                .collect();
            if !(buses.contains(&SocketCanBus::Main) && buses.contains(&SocketCanBus::Payload)) {
                err(
                    at(),
                    "replacing the PC needs a socketcan link replacing it on each bus (main and \
                     payload)"
                        .to_owned(),
                );
            }
        }
    }
    replaced_addrs
}

/// A KISS or hub link's addresses (one segment, no simulated node's unless replaced) and
/// limits.
fn check_kiss_fields(
    l: &LinkSpec,
    net: &NetworkSpec,
    i: usize,
    replaced_addrs: &[u8],
    p: &dyn Fn(&str) -> Vec<PathStep>,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    let addrs: Vec<u8> = l.addrs.iter().chain(replaced_addrs).copied().collect();
    // The hub's programs may sit on several segments; a KISS link joins one.
    if l.kind != LinkKind::ZmqHub
        && let Some(&first) = addrs.first()
        && let Some(&other) = addrs
            .iter()
            .find(|&&a| Segment::of(a) != Segment::of(first))
    {
        err(
            p("addrs"),
            format!(
                "{first} and {other} are on different segments; a KISS link joins one (12-15 \
                 payload bus, 16-20 ground, others main bus)"
            ),
        );
    }
    for (j, &a) in l.addrs.iter().enumerate() {
        let at = vec![
            key("links"),
            PathStep::Index(i),
            key("addrs"),
            PathStep::Index(j),
        ];
        if a >= 31 {
            err(at, format!("{a} is not a unicast CSP address"));
        } else if let Some(node) = net.nodes.iter().find(|n| n.addr == a)
            && !replaced_addrs.contains(&a)
        {
            err(
                at,
                format!(
                    "{a} is {}'s address: add replaces = [\"{}\"] to take its place, or \
                     use a free address",
                    node.name, node.name
                ),
            );
        }
    }
    for (f, v) in [
        ("max_connections", l.max_connections),
        ("input_chunks", l.input_chunks),
        ("output_frames", l.output_frames),
    ] {
        if let Some(v) = v
            && !(1..=65_536).contains(&v)
        {
            err(p(f), format!("{v} is out of range 1..=65536"));
        }
    }
    if let Some(v) = l.tx_frames_per_s
        && !(1..=100_000).contains(&v)
    {
        err(
            p("tx_frames_per_s"),
            format!("{v} is out of range 1..=100000"),
        );
    }
}

/// A socketcan link is the bus itself: none of a KISS link's fields.
fn check_socketcan_fields(
    l: &LinkSpec,
    p: &dyn Fn(&str) -> Vec<PathStep>,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    for f in [
        "addrs",
        "max_connections",
        "input_chunks",
        "output_frames",
        "idle_timeout",
        "tx_frames_per_s",
    ] {
        let set = match f {
            "addrs" => !l.addrs.is_empty(),
            "max_connections" => l.max_connections.is_some(),
            "input_chunks" => l.input_chunks.is_some(),
            "idle_timeout" => l.idle_timeout.is_some(),
            "tx_frames_per_s" => l.tx_frames_per_s.is_some(),
            _ => l.output_frames.is_some(),
        };
        if set {
            err(
                p(f),
                "a socketcan link is the bus itself: it has no addresses or KISS limits".to_owned(),
            );
        }
    }
}

/// A console link: a node of the twin, and nothing of a CSP link.
fn validate_uart(
    s: &Scenario,
    l: &LinkSpec,
    net: &NetworkSpec,
    p: &dyn Fn(&str) -> Vec<PathStep>,
    err: &mut dyn FnMut(Vec<PathStep>, String),
) {
    let s_replaces = |name: &str| {
        s.links
            .iter()
            .any(|o| o.replaces.iter().any(|r| r.eq_ignore_ascii_case(name)))
    };
    match &l.node {
        None => err(
            p("node"),
            "name the node whose console this is (node = \"FC\")".to_owned(),
        ),
        Some(name) => {
            if !net.nodes.iter().any(|n| n.name.eq_ignore_ascii_case(name)) {
                let names: Vec<&str> = net.nodes.iter().map(|n| n.name.as_str()).collect();
                err(
                    p("node"),
                    format!("unknown node `{name}` (nodes: {})", names.join(", ")),
                );
            } else if s_replaces(name) {
                err(
                    p("node"),
                    format!(
                        "{name} is replaced by an outside program: the twin has no console of it"
                    ),
                );
            }
        }
    }
    for (f, set) in [
        ("addrs", !l.addrs.is_empty()),
        ("replaces", !l.replaces.is_empty()),
        ("powered_by", l.powered_by.is_some()),
        ("libcsp14_rx_limit", l.libcsp14_rx_limit),
        ("max_connections", l.max_connections.is_some()),
        ("input_chunks", l.input_chunks.is_some()),
        ("output_frames", l.output_frames.is_some()),
        ("idle_timeout", l.idle_timeout.is_some()),
        ("tx_frames_per_s", l.tx_frames_per_s.is_some()),
    ] {
        if set {
            err(
                p(f),
                "a uart link is a node's text console: it carries no CSP and has no addresses, \
                 replaced nodes, power or KISS limits"
                    .to_owned(),
            );
        }
    }
}

/// Why a command line link cannot take a twin node's place.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CliReplaceError {
    /// A COMM: the twin's radio.
    #[error(
        "--kiss-addr {addr} is {node_name}'s address: a COMM carries the twin's UHF radio: it \
         cannot be replaced by an outside program"
    )]
    Comm {
        /// The address.
        addr: u8,
        /// The node's name.
        node_name: String,
    },
    /// The PC: on both CAN buses.
    #[error(
        "--kiss-addr {addr} is {node_name}'s address: the PC sits on both CAN buses and a KISS \
         link joins one segment: replace it with two socketcan links, one per bus"
    )]
    Pc {
        /// The address.
        addr: u8,
        /// The node's name.
        node_name: String,
    },
}

/// The command line's links (`--kiss-addr` after `--kiss-listen` and the others) take the
/// place of the twin's nodes at their addresses, as a scenario link's `replaces` does:
/// `--kiss-addr 12` is the user's payload 12, so the simulated PL12 is not started (before,
/// the link could never claim 12 and only logged a warning). Returns the replaced nodes'
/// addresses and names, each once; a COMM (the twin's radio) or the PC (on both buses) cannot be
/// replaced over KISS, as in a scenario.
pub fn cli_replaces<'a>(
    net: &NetworkSpec,
    links: impl IntoIterator<Item = &'a KissLinkConfig>,
) -> Result<Vec<(u8, String)>, CliReplaceError> {
    let mut out: Vec<(u8, String)> = Vec::new();
    for cfg in links {
        for &a in &cfg.addrs {
            let Some(node) = net.nodes.iter().find(|n| n.addr == a) else {
                continue;
            };
            let (addr, node_name) = (a, node.name.clone());
            match node.role {
                Role::CommPrimary | Role::CommSecondary => {
                    return Err(CliReplaceError::Comm { addr, node_name });
                }
                Role::Pc => return Err(CliReplaceError::Pc { addr, node_name }),
                _ => {}
            }
            if !out.iter().any(|(b, _)| *b == a) {
                out.push((a, node.name.clone()));
            }
        }
    }
    Ok(out)
}

/// Add the scenario's links to `opts`: each KISS link with its own addresses (its own and
/// those of the nodes it replaces) and limits, each SocketCAN bridge, the replaced nodes,
/// and every link's place in `opts.outside`.
pub fn compile(s: &Scenario, net: &NetworkSpec, opts: &mut RunOptions) {
    for l in &s.links {
        let replaced: Vec<u8> = l
            .replaces
            .iter()
            .filter_map(|r| net.nodes.iter().find(|n| n.name.eq_ignore_ascii_case(r)))
            .map(|n| n.addr)
            .collect();
        opts.replaced.extend(&replaced);
        // Every link gets its place in `opts.outside` (faults name it by its index).
        let label = match l.kind {
            LinkKind::KissListen
            | LinkKind::KissConnect
            | LinkKind::KissPty
            | LinkKind::ZmqHub
            | LinkKind::Udp => {
                let mut addrs = l.addrs.clone();
                addrs.extend(replaced.iter().filter(|a| !l.addrs.contains(a)));
                let defaults = KissLimits::default();
                let limits = KissLimits {
                    max_connections: l.max_connections.unwrap_or(defaults.max_connections),
                    input_chunks: l.input_chunks.unwrap_or(defaults.input_chunks),
                    output_frames: l.output_frames.unwrap_or(defaults.output_frames),
                    idle_timeout: l.idle_timeout.map_or(
                        defaults.idle_timeout,
                        twin_scenario::scenario::IdleLimit::duration,
                    ),
                };
                let mode = match l.kind {
                    LinkKind::KissListen => l.addr.parse().ok().map(KissMode::Listen),
                    LinkKind::KissConnect => l.addr.parse().ok().map(KissMode::Connect),
                    LinkKind::KissPty => Some(KissMode::Pty(l.addr.clone().into())),
                    LinkKind::Udp => l.addr.parse().ok().map(|bind| {
                        KissMode::Udp(links::udp::UdpAddr {
                            bind,
                            peer: l.peer.as_deref().and_then(|p| p.parse().ok()),
                        })
                    }),
                    _ => l.addr.parse().ok().map(KissMode::ZmqHub),
                };
                match mode {
                    Some(mode) => {
                        let mut link = KissLink::new(mode);
                        link.cfg.addrs = addrs;
                        link.cfg.limits = limits;
                        link.cfg.tx_frames_per_s = l.tx_frames_per_s;
                        link.cfg.decoder = csp::kiss::DecoderConfig {
                            libcsp14_rx_limit: l.libcsp14_rx_limit,
                        };
                        let label = link.label();
                        opts.kiss_links.push(link);
                        label
                    }
                    None => l.addr.clone(),
                }
            }
            LinkKind::Uart => {
                let at = match &l.pty {
                    Some(path) => Some(twin_runtime::UartAt::Pty(path.into())),
                    None => l.addr.parse().ok().map(twin_runtime::UartAt::Tcp),
                };
                let node = l.node.clone().unwrap_or_default();
                match at {
                    Some(at) => {
                        let link = twin_runtime::UartLink { node, at };
                        let label = link.label();
                        opts.uart.push(link);
                        label
                    }
                    None => format!("uart {node}"),
                }
            }
            LinkKind::Socketcan => match SocketCanBus::parse_arg(&l.addr) {
                Ok(link) => {
                    let label = format!("socketcan {}", link.0);
                    opts.socketcan.push(link);
                    label
                }
                Err(_) => format!("socketcan {}", l.addr),
            },
        };
        opts.outside.push(OutsideLink {
            name: l.name.clone().unwrap_or_else(|| label.clone()),
            label,
            powered_by: l
                .powered_by
                .as_deref()
                .and_then(nodes_eps::Channel::from_name),
        });
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn errors(links: &str) -> String {
        let text = format!("name = \"t\"\nduration = \"1m\"\n{links}");
        // Parsing validates.
        match crate::validate::parse("t.toml", &text) {
            Ok(_) => String::new(),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_console_link_names_a_node_of_the_twin_and_one_place_to_serve_it() {
        let ok = "[[links]]\nkind = \"uart\"\nnode = \"fc\"\naddr = \"127.0.0.1:5010\"\n\
                  [[links]]\nkind = \"uart\"\nnode = \"EPS\"\npty = \"/tmp/eps-uart\"\n";
        assert_eq!(errors(ok), "");
        let text = format!("name = \"t\"\nduration = \"1m\"\n{ok}");
        let s = crate::validate::parse("t.toml", &text).unwrap();
        let mut opts = crate::plan::compile(&s).opts;
        assert_eq!(opts.uart.len(), 2);
        assert_eq!(opts.uart[0].label(), "uart fc 127.0.0.1:5010");
        assert_eq!(
            opts.outside.len(),
            2,
            "faults index links in scenario order"
        );
        opts.uart.clear();
        for (links, field, says) in [
            (
                "kind = \"uart\"\naddr = \"127.0.0.1:5010\"",
                "node",
                "name the node",
            ),
            (
                "kind = \"uart\"\nnode = \"XX\"\naddr = \"127.0.0.1:5010\"",
                "node",
                "unknown node `XX`",
            ),
            (
                "kind = \"uart\"\nnode = \"FC\"\naddr = \"1.2.3.4:5\"\npty = \"/tmp/x\"",
                "pty",
                "not both",
            ),
            ("kind = \"uart\"\nnode = \"FC\"", "addr", "not an address"),
            (
                "kind = \"uart\"\nnode = \"FC\"\naddr = \"127.0.0.1:5010\"\naddrs = [3]",
                "addrs",
                "carries no CSP",
            ),
            (
                "kind = \"kiss-listen\"\naddr = \"127.0.0.1:5010\"\nnode = \"FC\"",
                "node",
                "only a `uart` link",
            ),
        ] {
            let e = errors(&format!("[[links]]\n{links}\n"));
            assert!(
                e.contains(&format!("links[0].{field}")) && e.contains(says),
                "{links}: {e}"
            );
        }
    }

    #[test]
    fn uart_arguments_are_a_node_and_an_address_or_a_path() {
        use twin_runtime::{UartAt, UartLink};
        let l = UartLink::parse_arg("FC=127.0.0.1:5010").unwrap();
        assert_eq!(l.at, UartAt::Tcp("127.0.0.1:5010".parse().unwrap()));
        let l = UartLink::parse_arg("EPS=/tmp/eps").unwrap();
        assert_eq!(l.at, UartAt::Pty("/tmp/eps".into()));
        for bad in ["FC", "=1.2.3.4:5", "FC=", "FC=localhost"] {
            assert!(UartLink::parse_arg(bad).is_err(), "{bad}");
        }
        assert_eq!(
            UartLink::parse_arg("FC").unwrap_err().to_string(),
            "`FC`: expected NODE=ADDR or NODE=PATH (FC=127.0.0.1:5010)"
        );
        assert_eq!(
            UartLink::parse_arg("FC=localhost"),
            Err(twin_runtime::LinkArgError::NotAddrOrPath {
                at: "localhost".into()
            })
        );
    }

    #[test]
    fn a_command_line_address_of_a_twin_node_replaces_it_unless_it_is_the_pc_or_a_comm() {
        let net = NetworkSpec::default_m6p();
        let link = |addrs: &[u8]| {
            let mut l = KissLink::listen("127.0.0.1:0".parse().unwrap());
            l.cfg.addrs = addrs.to_vec();
            l
        };
        let replaces = |links: &[KissLink]| cli_replaces(&net, links.iter().map(|l| &l.cfg));
        assert_eq!(
            replaces(&[link(&[17]), link(&[12])]).unwrap(),
            vec![(12, "PL12".to_owned())]
        );
        assert_eq!(
            replaces(&[link(&[6])]).unwrap_err().to_string(),
            "--kiss-addr 6 is PC's address: the PC sits on both CAN buses and a KISS link joins \
             one segment: replace it with two socketcan links, one per bus"
        );
        assert_eq!(
            replaces(&[link(&[1])]).unwrap_err(),
            CliReplaceError::Comm {
                addr: 1,
                node_name: "COMM1".into()
            }
        );
        assert_eq!(
            replaces(&[link(&[2])]).unwrap_err().to_string(),
            "--kiss-addr 2 is COMM2's address: a COMM carries the twin's UHF radio: it cannot be \
             replaced by an outside program"
        );
        // Two connections of one link (a replay's) name it once.
        assert_eq!(replaces(&[link(&[12]), link(&[12])]).unwrap().len(), 1);
    }

    #[test]
    fn a_twin_nodes_address_needs_replaces_and_a_kiss_link_cannot_replace_the_pc() {
        let e = errors("[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:1\"\naddrs = [3]\n");
        assert!(
            e.contains("links[0].addrs[0]") && e.contains("3 is FC's address"),
            "{e}"
        );
        let e = errors(
            "[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:1\"\nreplaces = [\"PC\"]\n",
        );
        assert!(e.contains("sits on both CAN buses"), "{e}");
        let e =
            errors("[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:1\"\naddrs = [14, 17]\n");
        assert!(e.contains("different segments"), "{e}");
        let e = errors("[[links]]\nkind = \"socketcan\"\naddr = \"vcan0\"\nreplaces = [\"PC\"]\n");
        assert!(e.contains("on each bus"), "{e}");
        let both = "[[links]]\nkind = \"socketcan\"\naddr = \"vcan0\"\nreplaces = [\"PC\"]\n\
                    [[links]]\nkind = \"socketcan\"\naddr = \"vcan1:payload\"\nreplaces = [\"PC\"]\n";
        assert_eq!(errors(both), "");
        assert!(errors("[[links]]\nkind = \"kiss-listen\"\naddr = \"127.0.0.1:1\"\nreplaces = [\"COMM1\"]\n").contains("UHF radio"));
    }

    #[test]
    fn a_replaced_node_is_not_started_and_its_address_is_the_links() {
        let text = "name = \"t\"\nduration = \"1m\"\n[[links]]\nkind = \"kiss-listen\"\n\
                    addr = \"127.0.0.1:1\"\nreplaces = [\"FC\"]\nmax_connections = 2\n\
                    [[links]]\nkind = \"kiss-connect\"\naddr = \"127.0.0.1:2\"\naddrs = [14]\n";
        let s = crate::validate::parse("t.toml", text).unwrap();
        let opts = crate::plan::compile(&s).opts;
        assert_eq!(opts.replaced.iter().copied().collect::<Vec<_>>(), vec![3]);
        assert_eq!(opts.kiss_links[0].cfg.addrs, vec![3]);
        assert_eq!(opts.kiss_links[0].cfg.limits.max_connections, 2);
        // Each link has its own addresses.
        assert_eq!(opts.kiss_links[1].cfg.addrs, vec![14]);
        assert_eq!(opts.kiss_links[1].label(), "connect 127.0.0.1:2");
    }
}
