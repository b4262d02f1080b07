//! TLS for the MQTT output: the rustls client configuration built from `[mqtt]`'s PEM files,
//! and the explanation of a failed TLS connection in words an operator can act on.
//!
//! What it is: [`client_config`], which reads `ca_file` (the only trust anchors: the system's
//! root store is not used, a fleet broker's certificate chains to the fleet's own CA), and
//! `cert_file` + `key_file` (this vehicle's client certificate, for mutual TLS) into a
//! [`rustls::ClientConfig`] on the `ring` provider, TLS 1.2 and 1.3; and [`explain`], which
//! finds the rustls error under a connection error and says which file or which side to check.
//! The broker is verified by rustls/webpki: the chain to `ca_file`, the validity dates, and
//! `mqtt.host` against the certificate's subject alternative names.
//!
//! What it is not: certificate management. Renewing the client certificate means writing new
//! files and restarting shimmyd; revocation lists are not read.

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{AlertDescription, CertificateError, ClientConfig, RootCertStore};

use super::config::MqttSection;

fn certs(key: &str, path: &Path) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let certs = CertificateDer::pem_file_iter(path)
        .and_then(|it| it.collect::<Result<Vec<_>, _>>())
        .map_err(|e| anyhow::anyhow!("{e:?}"))
        .with_context(|| {
            format!(
                "mqtt.{key}: cannot read certificates from {}",
                path.display()
            )
        })?;
    if certs.is_empty() {
        bail!(
            "mqtt.{key}: no PEM certificate (-----BEGIN CERTIFICATE-----) in {}",
            path.display()
        );
    }
    Ok(certs)
}

/// The TLS client configuration of `m` (whose transport is TLS and `ca_file` set: the
/// configuration check saw to it). Errors name the key and the file.
pub fn client_config(m: &MqttSection) -> anyhow::Result<Arc<ClientConfig>> {
    let ca = m
        .ca_file
        .as_deref()
        .context("mqtt.ca_file: required with TLS")?;
    let mut roots = RootCertStore::empty();
    for (i, c) in certs("ca_file", ca)?.into_iter().enumerate() {
        roots.add(c).map_err(|e| {
            anyhow::anyhow!(
                "mqtt.ca_file: certificate {} of {} is not a usable CA certificate: {e}",
                i + 1,
                ca.display()
            )
        })?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS: protocol versions")?
        .with_root_certificates(roots);
    let cfg = match (&m.cert_file, &m.key_file) {
        (Some(cert), Some(key)) => {
            let chain = certs("cert_file", cert)?;
            let k = PrivateKeyDer::from_pem_file(key)
                .map_err(|e| anyhow::anyhow!("{e:?}"))
                .with_context(|| {
                    format!(
                        "mqtt.key_file: no PEM private key (PKCS#8, PKCS#1 or SEC1) in {}",
                        key.display()
                    )
                })?;
            builder.with_client_auth_cert(chain, k).with_context(|| {
                format!(
                    "mqtt.cert_file / mqtt.key_file: {} and {} do not make a client identity",
                    cert.display(),
                    key.display()
                )
            })?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(Arc::new(cfg))
}

/// The first [`rustls::Error`] under `e` (through `source()` and [`std::io::Error`]'s inner).
fn rustls_cause<'a>(e: &'a (dyn std::error::Error + 'static)) -> Option<&'a rustls::Error> {
    let mut cur = Some(e);
    while let Some(err) = cur {
        if let Some(r) = err.downcast_ref::<rustls::Error>() {
            return Some(r);
        }
        if let Some(io) = err.downcast_ref::<std::io::Error>() {
            if let Some(r) = io.get_ref().and_then(|i| rustls_cause(i)) {
                return Some(r);
            }
        }
        cur = err.source();
    }
    None
}

/// `e` (a connection error with TLS configured) with what it most likely means. `None` when
/// no TLS cause is recognised (the error speaks for itself then).
pub fn explain(e: &(dyn std::error::Error + 'static), m: &MqttSection) -> Option<String> {
    let ca = m
        .ca_file
        .as_deref()
        .map_or(String::new(), |p| p.display().to_string());
    let cert = m
        .cert_file
        .as_deref()
        .map_or("(none)".to_string(), |p| p.display().to_string());
    let Some(cause) = rustls_cause(e) else {
        // Some layers keep only the text of an I/O error (rumqttc's MQTT 5 decoder): an alert
        // from the broker is still recognised by its rustls wording.
        let text = e.to_string();
        let name = text.split("received fatal alert: ").nth(1)?;
        let name: String = name.chars().take_while(|c| c.is_alphanumeric()).collect();
        let alert = [
            AlertDescription::CertificateExpired,
            AlertDescription::UnknownCA,
            AlertDescription::BadCertificate,
            AlertDescription::CertificateUnknown,
            AlertDescription::CertificateRevoked,
            AlertDescription::AccessDenied,
            AlertDescription::CertificateRequired,
            AlertDescription::HandshakeFailure,
        ]
        .into_iter()
        .find(|a| format!("{a:?}") == name)?;
        return explain_alert(alert, &cert);
    };
    match cause {
        rustls::Error::InvalidCertificate(c) => Some(match c {
            CertificateError::UnknownIssuer | CertificateError::BadSignature => format!(
                "the broker's certificate is not trusted: it does not chain to the CA in mqtt.ca_file {ca} ({c:?})"
            ),
            CertificateError::Expired | CertificateError::ExpiredContext { .. } => {
                format!("the broker's certificate has expired ({c:?})")
            }
            CertificateError::NotValidForName | CertificateError::NotValidForNameContext { .. } => {
                format!(
                    "the broker's certificate is not issued for mqtt.host = \"{}\" ({c:?})",
                    m.host
                )
            }
            other => format!("the broker's certificate was rejected: {other:?}"),
        }),
        rustls::Error::AlertReceived(a) => explain_alert(*a, &cert),
        rustls::Error::InvalidMessage(_) | rustls::Error::InappropriateMessage { .. } => Some(
            "the broker does not speak TLS on this port (a plain-TCP listener?); check mqtt.port"
                .to_string(),
        ),
        other => Some(format!("TLS: {other}")),
    }
}

/// What an alert from the broker says about this vehicle's certificate.
fn explain_alert(a: AlertDescription, cert: &str) -> Option<String> {
    Some(match a {
            AlertDescription::CertificateExpired => format!(
                "the broker refused this vehicle's client certificate: expired (mqtt.cert_file {cert})"
            ),
            AlertDescription::UnknownCA
            | AlertDescription::BadCertificate
            | AlertDescription::CertificateUnknown
            | AlertDescription::CertificateRevoked
            | AlertDescription::AccessDenied => format!(
                "the broker refused this vehicle's client certificate ({a:?}): not issued by a CA it trusts, revoked or not accepted (mqtt.cert_file {cert})"
            ),
            AlertDescription::CertificateRequired => format!(
                "the broker requires a client certificate and none is configured (mqtt.cert_file, mqtt.key_file)"
            ),
            other => format!("the broker ended the TLS session with alert {other:?}"),
    })
}
