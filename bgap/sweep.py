from bgap.runner.numerics import command

main = command("bgap.commands.sweep")
if __name__ == "__main__":
    main()
