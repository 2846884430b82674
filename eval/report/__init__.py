"""The soak's reports: report.json (build, schema, the baseline comparison), report.html
(html, plots; Jinja2 templates in eval/templates/) and junit.xml.
"""
