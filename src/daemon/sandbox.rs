//! The systemd sandbox a configuration needs beyond the unit's own.
//!
//! The unit (config/systemd/shimmyd.service) allows the address families the bus needs
//! (AF_CAN, AF_UNIX for sd_notify, AF_NETLINK for interface lookup) and no IP address at all.
//! With `[mqtt] enabled = true` shimmyd makes one outgoing TCP connection to the broker, so the
//! service needs AF_INET/AF_INET6 and the broker's address. This module writes that drop-in
//! ([`dropin`], printed by `shimmyd --sandbox-dropin`; the Debian package's systemd generator
//! installs it at boot and at every `systemctl daemon-reload`), and checks at start
//! ([`check_env`], run by `shimmyd --check`, the unit's `ExecStartPre`) that the sandbox the
//! service runs in was made from the configuration it is about to use: the unit and the
//! drop-in each set [`ENV`], naming what they allow.
//!
//! What it is not: the MQTT client ([`super::mqtt`]) or the unit file. Outside the unit
//! ([`ENV`] unset) nothing is checked.

use std::net::IpAddr;

use anyhow::bail;

use super::config::Config;

/// Set by the unit (`can`) and by the MQTT drop-in (`can,mqtt=<broker host>`).
pub const ENV: &str = "SHIMMYD_SANDBOX";

/// The drop-in file's name in `shimmyd.service.d/`.
pub const DROPIN_NAME: &str = "mqtt.conf";

/// What `IPAddressAllow=` gets for a broker host: the address itself, `localhost` for the
/// loopback name, `any` for another host name (its addresses are not known before the network
/// is up; the connection is still outgoing only).
fn ip_allow(host: &str) -> String {
    if let Ok(ip) = host.parse::<IpAddr>() {
        ip.to_string()
    } else if host.eq_ignore_ascii_case("localhost") {
        "localhost".into()
    } else {
        "any".into()
    }
}

/// A host name or address safe to write into a unit file (no whitespace, quotes or `%`
/// specifiers): letters, digits, `.`, `-`, `_` and `:` (IPv6).
fn host_is_plain(host: &str) -> bool {
    !host.is_empty()
        && host
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_' | ':'))
}

/// The drop-in `cfg` needs, or `None` when the unit's sandbox suffices (`[mqtt]` off).
/// `source` names the configuration file in the drop-in's comment.
pub fn dropin(cfg: &Config, source: &str) -> anyhow::Result<Option<String>> {
    if !cfg.mqtt.enabled {
        return Ok(None);
    }
    let host = cfg.mqtt.host.as_str();
    if !host_is_plain(host) {
        bail!(
            "mqtt.host {host:?}: not a host name or address that can go into a systemd unit \
             (letters, digits, '.', '-', '_', ':')"
        );
    }
    let allow = ip_allow(host);
    let why = match allow.as_str() {
        "any" => format!(
            "# mqtt.host {host} is a name, resolved only when the network is up: any IP address\n\
             # is allowed (outgoing; shimmyd opens no listener). Give the broker's address as\n\
             # mqtt.host to allow exactly that address.\n"
        ),
        _ => String::new(),
    };
    Ok(Some(format!(
        "# Made by `shimmyd --sandbox-dropin` from {source}: [mqtt] is enabled, so the service may\n\
         # open an outgoing TCP connection to the broker {host}:{port}. Regenerated at every\n\
         # `systemctl daemon-reload`; do not edit (put local changes in /etc/systemd/system/).\n\
         {why}[Service]\n\
         RestrictAddressFamilies=AF_INET AF_INET6\n\
         IPAddressAllow={allow}\n\
         Environment={ENV}=can,mqtt={host}\n",
        port = cfg.mqtt.port(),
    )))
}

/// What a [`ENV`] value allows: MQTT to which host, if at all.
fn mqtt_host(env: &str) -> Option<&str> {
    env.split(',').find_map(|t| t.strip_prefix("mqtt="))
}

/// Checks that the sandbox described by `env` (the value of [`ENV`], `None` outside the unit)
/// is the one `cfg` needs. An error when the configuration needs more than the sandbox allows
/// (the service would start and fail to connect); a warning (returned) when the sandbox allows
/// more than needed.
pub fn check_env(cfg: &Config, env: Option<&str>) -> anyhow::Result<Option<String>> {
    let Some(env) = env else {
        return Ok(None);
    };
    let reload = "run `systemctl daemon-reload` (the generator rewrites \
                  shimmyd.service.d/mqtt.conf from the configuration), then start shimmyd again";
    match (cfg.mqtt.enabled, mqtt_host(env)) {
        (true, None) => bail!(
            "[mqtt] is enabled but the service's sandbox allows no IP connection ({ENV}={env}): \
             {reload}"
        ),
        (true, Some(h)) if h != cfg.mqtt.host => bail!(
            "the service's sandbox allows the MQTT broker {h}, the configuration names {}: \
             {reload}",
            cfg.mqtt.host
        ),
        (false, Some(h)) => Ok(Some(format!(
            "[mqtt] is off but the service's sandbox still allows connections to {h}: {reload}"
        ))),
        _ => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(enabled: bool, host: &str) -> Config {
        let text = format!(
            "[input]\n[outputs]\njournal_dir = \"j\"\nstate_dir = \"s\"\n\
             [mqtt]\nenabled = {enabled}\nclient_id = \"van\"\n"
        );
        let mut c: Config = toml::from_str(&text).unwrap();
        c.mqtt.host = host.into();
        c
    }

    #[test]
    fn no_dropin_without_mqtt() {
        assert_eq!(dropin(&cfg(false, ""), "f").unwrap(), None);
    }

    #[test]
    fn dropin_allows_exactly_an_address() {
        let d = dropin(&cfg(true, "192.0.2.10"), "f").unwrap().unwrap();
        assert!(d.contains("\nIPAddressAllow=192.0.2.10\n"), "{d}");
        assert!(
            d.contains("\nRestrictAddressFamilies=AF_INET AF_INET6\n"),
            "{d}"
        );
        assert!(
            d.contains("\nEnvironment=SHIMMYD_SANDBOX=can,mqtt=192.0.2.10\n"),
            "{d}"
        );
        let d = dropin(&cfg(true, "2001:db8::1"), "f").unwrap().unwrap();
        assert!(d.contains("\nIPAddressAllow=2001:db8::1\n"), "{d}");
        let d = dropin(&cfg(true, "LocalHost"), "f").unwrap().unwrap();
        assert!(d.contains("\nIPAddressAllow=localhost\n"), "{d}");
        let d = dropin(&cfg(true, "broker.example"), "f").unwrap().unwrap();
        assert!(d.contains("\nIPAddressAllow=any\n"), "{d}");
    }

    #[test]
    fn host_that_cannot_go_into_a_unit_is_refused() {
        for h in ["a b", "x%n", "a\"b", "h\nIPAddressAllow=any"] {
            let e = dropin(&cfg(true, h), "f").unwrap_err().to_string();
            assert!(e.contains("mqtt.host"), "{e}");
        }
    }

    #[test]
    fn sandbox_must_match_the_configuration() {
        assert!(check_env(&cfg(true, "192.0.2.10"), None).unwrap().is_none());
        assert!(check_env(&cfg(false, ""), Some("can")).unwrap().is_none());
        let e = check_env(&cfg(true, "192.0.2.10"), Some("can")).unwrap_err();
        assert!(e.to_string().contains("daemon-reload"), "{e}");
        let e = check_env(&cfg(true, "192.0.2.11"), Some("can,mqtt=192.0.2.10")).unwrap_err();
        assert!(e.to_string().contains("192.0.2.11"), "{e}");
        assert!(
            check_env(&cfg(true, "192.0.2.10"), Some("can,mqtt=192.0.2.10"))
                .unwrap()
                .is_none()
        );
        let w = check_env(&cfg(false, ""), Some("can,mqtt=192.0.2.10")).unwrap();
        assert!(w.unwrap().contains("[mqtt] is off"));
    }
}
